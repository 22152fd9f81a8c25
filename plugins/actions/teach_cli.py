"""``vgr teach photo|install RECIPE``: store the robot's current pose as the recipe's taught pose.

The technician jogs the robot to the photo (or install) pose and runs the verb. It starts the
recipe's robot stage alone (the stage wired to the guidance's ``robot`` client, or ``--robot``),
asks its ``state`` service for ``T_base_tcp`` and writes it into the recipe in place: the value of
``vars.photo_pose`` / ``vars.install_pose`` if the recipe has that variable, else the
``photo_pose`` / ``install_pose`` parameter of the guidance / docking stage. Only that value's text
changes; comments and layout are kept, and the old value is printed. ``--pose x,y,z,rx,ry,rz``
(m, rotation vector rad; the UR pendant's notation) stores a pose read elsewhere instead, refused
when the robot cannot reach it (an adapter's workspace box, a robot model's reach, 10 m for any
robot): a pendant's millimetres typed as metres are caught.

Teaching a new photo pose invalidates the matcher template (captured at the old one): the verb
says so. Nothing moves the robot.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rich.console import Console

from engine.errors import RecipeError
from engine.exit_codes import ExitCode
from engine.files import replace_text
from engine.graph import build_graph
from engine.messages import Event, Message, Request
from engine.plugin_manager import PluginError, load_registry
from engine.recipe.model import load_recipe
from engine.transforms import as_transform
from plugins.util.detached import DetachedContext
from plugins.vendor_poses import T_from_ur

out = Console()
WHAT = {"photo": ("photo_pose", "guidance"), "install": ("install_pose", ("docking", "dual_docking"))}


class TeachError(Exception):
    """The pose cannot be taught (bad recipe, no robot, robot did not answer)."""


class _QuietContext(DetachedContext):
    """A detached robot stage answering ``state``: warnings printed, no services of its own to call."""

    def event(self, level: str, code: str, message: str, **details: Any) -> None:
        if level in ("warning", "error", "alarm"):
            out.print(f"[yellow]{level}[/] {self.name}: {Event(message=message).message}", highlight=False)

    def call(self, client: str, request: Message, timeout_s: float = 10.0) -> Message:
        raise TeachError(f"the robot stage {self.name!r} needs service {client!r} to report its state")


def _stage_of(doc: dict[str, Any], types: str | tuple[str, ...]) -> str | None:
    wanted = (types,) if isinstance(types, str) else types
    names = [n for n, s in (doc.get("stages") or {}).items() if isinstance(s, dict) and s.get("type") in wanted]
    if len(names) > 1:
        raise TeachError(f"several {'/'.join(wanted)} stages ({', '.join(names)}): say which with --stage")
    return names[0] if names else None


def robot_stage(recipe: Path, doc: Any, robot: str | None) -> tuple[str, Any]:
    """(name, spec) of the robot stage of *recipe* (loaded: *doc*): *robot*, else the one the first
    robot client uses."""
    if robot is None:
        users = [s for s in doc.stages.values() if "robot" in s.uses]
        if not users:
            raise TeachError("no stage uses a robot: name the robot stage with --robot")
        robot = users[0].uses["robot"].split(".")[0]
    if robot not in doc.stages:
        raise TeachError(f"no stage {robot!r} in {recipe} (stages: {', '.join(doc.stages)})")
    return robot, doc.stages[robot]


# farther than this from any robot's base is a number in the wrong unit, whatever the robot
MAX_PLAUSIBLE_REACH_M = 10.0


def reach_problem(name: str, spec: Any, T_base_tcp: np.ndarray) -> str | None:
    """Why the robot stage *name* cannot reach *T_base_tcp*, or None: outside an adapter's workspace
    box (``workspace_min_m`` / ``workspace_max_m``), beyond a robot model's reach (``model``: the sum
    of its link lengths and the tool's), or beyond any robot's reach."""
    t = np.asarray(T_base_tcp, dtype=float)[:3, 3]
    dist = float(np.linalg.norm(t))
    hint = "were the numbers millimetres? --pose takes metres"
    params = spec.params
    if "workspace_min_m" in params and "workspace_max_m" in params:
        lo, hi = np.asarray(params["workspace_min_m"], float), np.asarray(params["workspace_max_m"], float)
        if np.any(t < lo) or np.any(t > hi):
            box = f"{lo.tolist()}..{hi.tolist()} m"
            return f"the pose {np.round(t, 4).tolist()} m is outside {name}'s workspace box {box} ({hint})"
    elif isinstance(params.get("model"), str):
        from plugins.params import PoseSpec
        from plugins.robot.model_file import load_robot_model

        model = load_robot_model(params["model"])
        tool = params.get("T_flange_tcp")
        if tool is not None:
            model = model.with_tool(PoseSpec.model_validate(tool).T())
        reach = model.chain.reach_bound(skip_groups=("base",))
        if dist > reach:
            robot = params["model"]
            return f"the pose is {dist:.3f} m from {name}'s base, beyond the {robot}'s reach {reach:.3f} m ({hint})"
    if dist > MAX_PLAUSIBLE_REACH_M:
        return f"the pose is {dist:.1f} m from the robot's base, beyond any robot's reach ({hint})"
    return None


def robot_pose(recipe: Path, robot: str | None) -> np.ndarray:
    """T_base_tcp reported by the recipe's robot stage (started alone, then closed)."""
    doc = load_recipe(str(recipe)).recipe
    robot, spec = robot_stage(recipe, doc, robot)
    cls = load_registry(doc.plugins).stage(spec.type)
    if "state" not in cls.services:
        raise TeachError(f"stage {robot!r} ({spec.type}) has no state service")
    stage = cls(_QuietContext(robot, doc.seed, recipe.resolve().parent), cls.Params(**spec.params))
    stage.setup()
    try:
        reply = stage.on_request("state", Request(command="teach"))
    finally:
        stage.teardown()
    if not getattr(reply, "ok", False) or reply.T is None:
        raise TeachError(f"the robot did not report its pose: {getattr(reply, 'error', '')}")
    return as_transform(reply.T, name="T_base_tcp")


def _value_node(root: yaml.Node, path: list[str]) -> yaml.Node | None:
    node = root
    for key in path:
        if not isinstance(node, yaml.MappingNode):
            return None
        node = next((v for k, v in node.value if isinstance(k, yaml.ScalarNode) and k.value == key), None)
        if node is None:
            return None
    return node


def pose_text(T: np.ndarray) -> str:
    """Flow-style ``{matrix: ...}``: rotation to 1e-9 (stays orthonormal within the recipe check),
    translation to 1 um."""

    def num(v: float, digits: int) -> str:
        return repr(round(float(v), digits) + 0.0)  # + 0.0: no "-0.0"

    rows = []
    for i, row in enumerate(np.asarray(T, dtype=float)):
        cells = [num(v, 6 if (j == 3 and i < 3) else 9) for j, v in enumerate(row)]
        rows.append("[" + ", ".join(c[:-2] if c.endswith(".0") else c for c in cells) + "]")
    return "{matrix: [" + ", ".join(rows) + "]}"


def taught_text(recipe: Path, what: str, T: np.ndarray, stage: str | None) -> tuple[str, str, str]:
    """*recipe*'s text with the taught pose's value replaced (the file is not written): (new text,
    where, old value text)."""
    key, types = WHAT[what]
    text = recipe.read_text()
    root = yaml.compose(text)
    candidates: list[list[str]] = [["vars", key]]
    doc = yaml.safe_load(text) or {}
    name = stage or _stage_of(doc, types)
    if name:
        candidates.append(["stages", name, "params", key])
    for path in candidates:
        node = _value_node(root, path)
        if node is None:
            continue
        if isinstance(node, yaml.ScalarNode) and "${" in str(node.value):
            continue  # the stage parameter refers to a variable: that variable was tried first
        start, end = node.start_mark.index, node.end_mark.index
        return text[:start] + pose_text(T) + text[end:], ".".join(path), text[start:end]
    raise TeachError(
        f"{recipe} has no vars.{key} and no {key} parameter of a {'/'.join(np.atleast_1d(types))} stage to write to"
    )


def cmd_teach(args: argparse.Namespace) -> int:
    recipe = Path(args.recipe)
    try:
        if not recipe.is_file():
            raise TeachError(f"no such recipe: {recipe}")
        if args.pose:
            vals = [float(v) for v in args.pose.split(",")]
            if len(vals) != 6 or not np.all(np.isfinite(vals)):
                raise TeachError("--pose must be 6 finite numbers x,y,z,rx,ry,rz (m, rotation vector rad)")
            T = T_from_ur(vals)
            name, spec = robot_stage(recipe, load_recipe(str(recipe)).recipe, args.robot)
            if (problem := reach_problem(name, spec, T)) is not None:
                raise TeachError(problem)
        else:
            T = robot_pose(recipe, args.robot)
        new_text, where, old = taught_text(recipe, args.what, T, args.stage)
        # the taught recipe must pass what `vgr validate` checks (stage parameters included) before
        # it replaces the file: a refused teach leaves the recipe as it was
        loaded = load_recipe(str(recipe), text=new_text)
        build_graph(loaded, load_registry(loaded.recipe.plugins))
        replace_text(recipe, new_text)  # atomic: a crash never leaves half a recipe
    except (TeachError, RecipeError, PluginError, ValueError, OSError, yaml.YAMLError) as exc:
        out.print(f"[red]cannot teach[/]: {exc}", highlight=False, soft_wrap=True)
        return ExitCode.INVALID
    out.print(f"taught {args.what} pose written to {recipe} at {where}", highlight=False)
    out.print(f"  was: {old}", highlight=False, soft_wrap=True)
    out.print(f"  now: {pose_text(T)}", highlight=False, soft_wrap=True)
    if args.what == "photo":
        out.print(
            "[yellow]the matcher template was taught at the old photo pose: teach it again[/] "
            "(run the teach recipe, then `vgr template make`)",
            highlight=False,
        )
    return ExitCode.OK


def add_verbs(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("teach", help="store the robot's current pose as the recipe's photo or install pose")
    p.add_argument("what", choices=sorted(WHAT))
    p.add_argument("recipe")
    p.add_argument("--robot", help="robot stage to ask (default: the one the guidance uses)")
    p.add_argument("--stage", help="guidance/docking stage whose parameter to write, if the recipe has several")
    p.add_argument("--pose", help="store this pose instead: x,y,z,rx,ry,rz (m, rotation vector rad)")
    p.set_defaults(func=cmd_teach)
