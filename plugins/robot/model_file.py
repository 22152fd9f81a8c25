"""Robot model files (YAML): schema, validation (pydantic) and the loader recipes use.

A recipe names a shipped model (``ur5e``, ``abb_irb120``: files in ``plugins/robot/robots/``) or
gives a path to a model file. Units are metres and radians (angles may be written ``pi/2``,
``-2*pi`` ..., or with an explicit unit ``165deg``); limits in rad, rad/s, rad/s^2.
Format (docs/kinematics.md has the full text)::

    name: ur5e
    convention: dh            # dh | mdh | poe
    joints:                   # dh/mdh: a, alpha, d, theta (zero offset), beta (Hayati, default 0)
      - {a: 0.0, alpha: pi/2, d: 0.1625, lower: -2*pi, upper: 2*pi, max_speed: pi, max_accel: 10}
                              # poe: axis: [wx, wy, wz], point: [x, y, z] (base frame, q = 0)
    flange_at_zero: {...}     # poe only: flange pose at q = 0 (M)
    last_to_flange: {...}     # dh/mdh, optional: last joint frame -> mechanical flange
    base: {xyz: [..], rpy: [..]}   # T_world_base (default identity)
    tool: {xyz: [..], rpy: [..]}   # T_flange_tcp (default identity)
    links:                    # optional, one per joint, for gravity torque
      - {mass: 3.761, com_link: [0, -0.02561, 0.00193]}   # or com_base_at_zero: [x, y, z]
    gravity: [0, 0, -9.80665] # world frame, m/s^2
    home: [0, -pi/2, ...]     # optional

Transforms are ``{xyz, rpy}`` (rpy = URDF roll-pitch-yaw: ``R = Rz(yaw) Ry(pitch) Rx(roll)``),
``{xyz, quat_xyzw}`` or ``{matrix: 4x4}``; a matrix that is not a rigid transform is rejected.
"""

from __future__ import annotations

import difflib
import re
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, model_validator

from engine.plain_data import read_document
from engine.transforms import T_from_pose7, T_from_Rt, as_transform, inv
from plugins.robot.conventions import DHRow, PoeJoint, build_chain
from plugins.robot.kinematics import JointSpec, LinkInertia, RobotModel

ROBOTS_DIR = Path(__file__).parent / "robots"

_DEG_EXPR = re.compile(r"^\s*([+-]?(?:\d+(?:\.\d*)?|\.\d+))\s*deg\s*$")
_PI_EXPR = re.compile(r"^\s*([+-])?\s*(\d+(?:\.\d*)?|\.\d+)?\s*\*?\s*pi\s*(?:/\s*(\d+(?:\.\d*)?))?\s*$")


def parse_angle(v: Any) -> float:
    """A number, a string like ``pi``, ``-pi/2``, ``2*pi``, ``0.5pi`` (radians) or ``165deg`` (-> rad)."""
    if isinstance(v, bool):
        raise ValueError("expected a number, got a boolean")
    if isinstance(v, int | float):
        return float(v)
    if isinstance(v, str):
        m_deg = _DEG_EXPR.match(v)
        if m_deg:
            return float(np.radians(float(m_deg.group(1))))
        m = _PI_EXPR.match(v)
        if m:
            sign = -1.0 if m.group(1) == "-" else 1.0
            num = float(m.group(2)) if m.group(2) else 1.0
            den = float(m.group(3)) if m.group(3) else 1.0
            if den == 0:
                raise ValueError(f"division by zero in {v!r}")
            return sign * num * np.pi / den
        try:
            return float(v)
        except ValueError:
            pass
    raise ValueError(f"expected a number or an expression like 'pi/2', got {v!r}")


def _finite(v: Any) -> float:
    x = parse_angle(v)
    if not np.isfinite(x):
        raise ValueError(f"value must be finite, got {v!r}")
    return x


Number = Annotated[float, BeforeValidator(_finite)]
Vec3 = tuple[Number, Number, Number]


class TransformSpec(BaseModel):
    """A rigid transform: ``xyz`` + ``rpy`` or ``quat_xyzw``, or a full ``matrix``."""

    model_config = ConfigDict(extra="forbid")
    xyz: Vec3 | None = None
    rpy: Vec3 | None = None
    quat_xyzw: tuple[Number, Number, Number, Number] | None = None
    matrix: list[list[Number]] | None = None

    @model_validator(mode="after")
    def _one_form(self) -> TransformSpec:
        if self.matrix is not None and any(x is not None for x in (self.xyz, self.rpy, self.quat_xyzw)):
            raise ValueError("give either 'matrix' or 'xyz' with 'rpy'/'quat_xyzw', not both")
        if self.rpy is not None and self.quat_xyzw is not None:
            raise ValueError("give either 'rpy' or 'quat_xyzw', not both")
        self.to_matrix()  # rigidity check with a clear message
        return self

    def to_matrix(self) -> np.ndarray:
        if self.matrix is not None:
            return as_transform(np.array(self.matrix, dtype=float), name="matrix")
        xyz = np.zeros(3) if self.xyz is None else np.array(self.xyz)
        if self.quat_xyzw is not None:
            return T_from_pose7(xyz, self.quat_xyzw)
        from scipy.spatial.transform import Rotation

        rpy = (0.0, 0.0, 0.0) if self.rpy is None else self.rpy
        return T_from_Rt(Rotation.from_euler("xyz", rpy).as_matrix(), xyz)


class JointEntry(BaseModel):
    """One joint: geometry (dh/mdh: a, alpha, d, theta, beta; poe: axis, point) and limits."""

    model_config = ConfigDict(extra="forbid")
    name: str | None = None
    a: Number | None = None
    alpha: Number | None = None
    d: Number | None = None
    theta: Number = 0.0
    beta: Number = 0.0
    axis: Vec3 | None = None
    point: Vec3 | None = None
    lower: Number
    upper: Number
    max_speed: Number = Field(description="rad/s")
    max_accel: Number = Field(description="rad/s^2")


class LinkEntry(BaseModel):
    """Mass (kg) and centre of mass of one link: in its link frame, or in the base frame at q = 0."""

    model_config = ConfigDict(extra="forbid")
    mass: Number = Field(ge=0.0)
    com_link: Vec3 | None = None
    com_base_at_zero: Vec3 | None = None

    @model_validator(mode="after")
    def _one_com(self) -> LinkEntry:
        if (self.com_link is None) == (self.com_base_at_zero is None):
            raise ValueError("give exactly one of 'com_link' and 'com_base_at_zero'")
        return self


class RobotFile(BaseModel):
    """The whole model file."""

    model_config = ConfigDict(extra="forbid")
    name: str = Field(min_length=1)
    description: str = ""
    sources: list[str] = []
    convention: Literal["dh", "mdh", "poe"]
    joints: list[JointEntry] = Field(min_length=1)
    flange_at_zero: TransformSpec | None = None
    last_to_flange: TransformSpec | None = None
    base: TransformSpec = TransformSpec()
    tool: TransformSpec = TransformSpec()
    links: list[LinkEntry] | None = None
    gravity: Vec3 = (0.0, 0.0, -9.80665)
    home: list[Number] | None = None

    @model_validator(mode="after")
    def _consistent(self) -> RobotFile:
        n = len(self.joints)
        for i, j in enumerate(self.joints, start=1):
            if self.convention == "poe":
                if j.axis is None or j.point is None:
                    raise ValueError(f"joint {i}: a poe joint needs 'axis' and 'point'")
                if any(v is not None for v in (j.a, j.alpha, j.d)):
                    raise ValueError(f"joint {i}: a poe joint takes no a/alpha/d")
                norm = float(np.linalg.norm(j.axis))
                if abs(norm - 1.0) > 1e-6:
                    raise ValueError(f"joint {i}: axis must be a unit vector (norm {norm:.6g})")
            else:
                if j.a is None or j.alpha is None or j.d is None:
                    raise ValueError(f"joint {i}: a {self.convention} joint needs 'a', 'alpha' and 'd'")
                if j.axis is not None or j.point is not None:
                    raise ValueError(f"joint {i}: a {self.convention} joint takes no axis/point")
        if self.convention == "poe" and self.flange_at_zero is None:
            raise ValueError("a poe model needs 'flange_at_zero' (the flange pose at q = 0)")
        if self.convention != "poe" and self.flange_at_zero is not None:
            raise ValueError("'flange_at_zero' is for poe models; dh/mdh use 'last_to_flange'")
        if self.links is not None and len(self.links) != n:
            raise ValueError(f"'links' must have one entry per joint ({n}), got {len(self.links)}")
        if self.home is not None and len(self.home) != n:
            raise ValueError(f"'home' must have {n} values, got {len(self.home)}")
        return self


def _format_validation_error(err: ValidationError, source: str) -> str:
    lines = [f"invalid robot model file {source}:"]
    for e in err.errors():
        loc = ".".join(str(x) for x in e["loc"]) or "(top level)"
        lines.append(f"  {loc}: {e['msg']}")
    return "\n".join(lines)


def robot_model_from_dict(data: Any, source: str = "<dict>") -> RobotModel:
    """Build a :class:`RobotModel` from the parsed content of a model file."""
    if not isinstance(data, dict):
        raise ValueError(f"robot model file {source} must be a mapping, got {type(data).__name__}")
    try:
        spec = RobotFile.model_validate(data)
        return _build(spec)
    except ValidationError as e:
        raise ValueError(_format_validation_error(e, source)) from None
    except ValueError as e:
        raise ValueError(f"invalid robot model file {source}: {e}") from None


def _build(spec: RobotFile) -> RobotModel:
    n = len(spec.joints)
    if spec.convention == "poe":
        joints: list = [PoeJoint(tuple(j.axis), tuple(j.point)) for j in spec.joints]  # type: ignore[arg-type]
        chain = build_chain(
            "poe",
            joints,
            T_world_base=spec.base.to_matrix(),
            T_flange_tcp=spec.tool.to_matrix(),
            M_flange_at_zero=spec.flange_at_zero.to_matrix(),  # type: ignore[union-attr]
        )
    else:
        joints = [DHRow(j.a, j.alpha, j.d, j.theta, j.beta) for j in spec.joints]  # type: ignore[arg-type]
        chain = build_chain(
            spec.convention,
            joints,
            T_world_base=spec.base.to_matrix(),
            T_flange_tcp=spec.tool.to_matrix(),
            T_last_flange=None if spec.last_to_flange is None else spec.last_to_flange.to_matrix(),
        )
    specs = [
        JointSpec(j.name or f"joint{i}", j.lower, j.upper, j.max_speed, j.max_accel)
        for i, j in enumerate(spec.joints, start=1)
    ]
    model = RobotModel(
        spec.name,
        spec.convention,
        chain,
        specs,
        gravity_world=spec.gravity,
        description=spec.description,
        sources=spec.sources,
        home=spec.home,
    )
    if spec.links is None:
        return model
    # link frames at q = 0 in the *base* frame, to express com_base_at_zero in link coordinates
    F0 = model.link_frames(np.zeros(n))
    T_bw = inv(model.T_world_base)
    links = []
    for j, link in enumerate(spec.links):
        if link.com_link is not None:
            c = np.array(link.com_link)
        else:
            F_base = T_bw @ F0[j]
            c = (inv(F_base) @ np.append(link.com_base_at_zero, 1.0))[:3]
        links.append(LinkInertia(float(link.mass), (float(c[0]), float(c[1]), float(c[2]))))
    return model.with_links(links)


def list_robot_models() -> list[str]:
    """Names of the shipped robot models."""
    return sorted(p.stem for p in ROBOTS_DIR.glob("*.yaml"))


def load_robot_model(name_or_path: str | Path) -> RobotModel:
    """Load a shipped model by name (``ur5e``) or a model file by path.

    Unknown names raise ValueError naming the closest shipped model.
    """
    if not isinstance(name_or_path, str | Path):
        raise ValueError(f"robot model must be a name or a path, got {type(name_or_path).__name__}")
    text = str(name_or_path)
    path = Path(text)
    looks_like_path = isinstance(name_or_path, Path) or path.suffix in (".yaml", ".yml") or "/" in text
    if not looks_like_path:
        shipped = list_robot_models()
        if text not in shipped:
            close = difflib.get_close_matches(text.lower(), shipped, n=1, cutoff=0.3)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(
                f"unknown robot model {text!r}{hint} Shipped models: {', '.join(shipped)}; "
                "or give the path of a model file (.yaml)"
            )
        path = ROBOTS_DIR / f"{text}.yaml"
    return robot_model_from_dict(read_document(path, "yaml", "robot model file"), source=str(path))


def transform_entry(T: np.ndarray) -> dict[str, Any]:
    """A 4x4 transform as recipe/model-file data: ``{"matrix": [[...], ...]}`` of plain floats."""
    return {"matrix": [[float(v) for v in row] for row in np.asarray(T)]}


def model_to_dict(model: RobotModel) -> dict[str, Any]:
    """A model-file mapping that :func:`robot_model_from_dict` turns back into the same robot.

    Errors on the base and tool are folded into their transforms; a POE model's joint errors into its
    screws. Floats are written in full precision (``repr``), so the round trip is exact to rounding.
    """
    joints: list[dict[str, Any]] = []
    limits = [{k: getattr(j, k) for k in ("name", "lower", "upper", "max_speed", "max_accel")} for j in model.joints]
    out: dict[str, Any] = {
        "name": model.name,
        "description": model.description,
        "sources": list(model.sources),
        "convention": model.convention,
    }
    if model.convention == "poe":
        screws, M = model.poe_screws_at_zero()
        for lim, sc in zip(limits, screws, strict=True):
            joints.append({"axis": list(sc.axis), "point": list(sc.point)} | lim)
        out["flange_at_zero"] = transform_entry(M)
    else:
        for lim, row in zip(limits, model.dh_rows(), strict=True):
            joints.append({k: getattr(row, k) for k in ("a", "alpha", "d", "theta", "beta")} | lim)
        out["last_to_flange"] = transform_entry(model._fixed_matrix("flange"))
    out["joints"] = joints
    out["base"] = transform_entry(model.T_world_base)
    out["tool"] = transform_entry(model.T_flange_tcp)
    if model.links is not None:
        out["links"] = [{"mass": link.mass_kg, "com_link": list(link.com_link)} for link in model.links]
    out["gravity"] = [float(g) for g in model.gravity_world]
    out["home"] = [float(v) for v in model.home]
    return out


def save_robot_model(model: RobotModel, path: str | Path) -> Path:
    """Write ``model`` as a model file (YAML) that :func:`load_robot_model` reads back."""
    path = Path(path)
    path.write_text(yaml.safe_dump(model_to_dict(model), sort_keys=False), encoding="utf-8")
    return path
