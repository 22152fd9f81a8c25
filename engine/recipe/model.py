"""Recipes: the YAML an integrator writes, validated into a typed model.

A recipe names its stages (type, parameters, inputs wired to other stages' outputs as
``stage.port``, services it uses as ``stage.service``, the process it runs in), its seed, its
clock, and its zenoh settings. Example::

    vgr: 1
    name: demo
    seed: 42
    vars: {n_points: 2000}
    stages:
      source: {type: synthetic_cloud, params: {n_points: "${n_points}", frames: 20}}
      move:   {type: transform_cloud, inputs: {cloud: source.cloud}, params: {translation_m: [0.01, 0, 0]}}
      stats:  {type: cloud_stats, inputs: {cloud: move.cloud}}

``${name}`` in a string of ``stages`` or ``serve.gateways`` is replaced by ``vars.name`` (the whole
string keeps the var's type).
Command-line overrides (``-p stage.param=value``, ``-p vars.name=value``, ``-p seed=7``) are applied
before validation; values are parsed as YAML scalars. Stage parameters are validated against the
stage type's own model by engine.graph, which also checks wiring, types and cycles.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, get_args, get_origin

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from engine.errors import Problem, RecipeError, nearest
from engine.recipe.endpoint_syntax import check_endpoints
from engine.recipe.yaml_source import Locations, load_with_locations, locate
from engine.security.tls import SecuritySettings

NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_-]{0,63}$")
_VAR_RE = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}")
RECIPE_FORMAT = 1


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ZenohSettings(_Strict):
    """Zenoh session of one process. ``listen`` unset is the embedded default (engine.transport.session_config):
    no listener for a single-process run, private unix sockets between the processes of one host."""

    mode: Literal["peer", "client", "router"] = "peer"
    listen: list[str] | None = None
    connect: list[str] = Field(default_factory=list)
    multicast_scouting: bool = False
    shared_memory: bool = True  # large payloads to processes of this host through shared memory (engine.transport.shm)
    # messages to the stages of other processes of this host over vgr's own unix sockets, not zenoh
    # (engine.transport.local_link; never with a security: block, whose TLS and access control every message takes)
    local_links: bool = True

    @field_validator("listen", "connect")
    @classmethod
    def _endpoints(cls, v: list[str] | None) -> list[str] | None:
        return None if v is None else check_endpoints(v)


class ProcessSettings(_Strict):
    """Per-process overrides of the zenoh endpoints (for recipes spread over processes/hosts)."""

    listen: list[str] | None = None
    connect: list[str] | None = None

    @field_validator("listen", "connect")
    @classmethod
    def _endpoints(cls, v: list[str] | None) -> list[str] | None:
        return None if v is None else check_endpoints(v)


class StageSpec(_Strict):
    type: str
    params: dict[str, Any] = Field(default_factory=dict)
    inputs: dict[str, str] = Field(default_factory=dict)
    uses: dict[str, str] = Field(default_factory=dict)
    process: str = "main"
    dispatch: Literal["auto", "thread"] = "auto"  # auto: run handlers inline on a local producer's thread when idle
    description: str = ""

    @field_validator("process")
    @classmethod
    def _process_name(cls, v: str) -> str:
        if not NAME_RE.match(v):
            raise ValueError("process names use letters, digits, '_' and '-', starting with a letter")
        return v


class RecordSettings(_Strict):
    """Recording of the run to MCAP (see engine.recording.recorder)."""

    enabled: bool = True
    path: str | None = None  # file or directory; default runs/<timestamp>-<recipe>.mcap
    flush_interval_s: float = Field(1.0, gt=0.0, le=60.0)
    compression: Literal["zstd", "lz4", "none"] = "zstd"
    chunk_size: int = Field(1 << 20, ge=1024)


class CycleRecordSettings(_Strict):
    """Rolling recordings of a cell service (engine.recording.cycle_files): a new file every
    ``cycles_per_file`` cycles, the oldest removed beyond any of the limits (0: no limit of that kind)."""

    cycles_per_file: int = Field(1, ge=1, le=100_000)
    keep_files: int = Field(1000, ge=0)
    keep_mb: float = Field(2000.0, ge=0.0)
    keep_hours: float = Field(0.0, ge=0.0)


class ServeSettings(_Strict):
    """A recipe hosted as a cell service (``vgr serve``, engine.run.cell): its cell name, which stage
    service answers each job command, how many replies it remembers, its recordings and gateways."""

    cell: str = Field(pattern=r"^[A-Za-z][A-Za-z0-9_-]{0,63}$")
    commands: dict[Literal["locate", "guide"], str] = Field(min_length=1)  # command -> "stage.service"
    remember: int = Field(1000, ge=1, le=1_000_000)  # replies kept for repeated request ids
    cycle_timeout_s: float = Field(30.0, gt=0.0, le=3600.0)
    record: CycleRecordSettings = Field(default_factory=CycleRecordSettings)
    gateways: dict[str, dict[str, Any]] = Field(default_factory=dict)  # name -> its settings (hook vgr_cell_gateways)


class Recipe(_Strict):
    vgr: int = RECIPE_FORMAT
    name: str
    description: str = ""
    seed: int = 0
    clock: Literal["wall", "sim"] = "wall"
    run_id: str | None = None
    on_error: Literal["stop", "continue"] = "stop"
    # a process of a multi-process run that starts again mid-run (a new epoch) is refused, and one
    # that vanishes without finishing fails the run, unless this is true (engine.transport.peers, docs/design.md)
    rejoin: bool = False
    plugins: list[str] = Field(default_factory=list)
    vars: dict[str, Any] = Field(default_factory=dict)
    zenoh: ZenohSettings = Field(default_factory=ZenohSettings)
    processes: dict[str, ProcessSettings] = Field(default_factory=dict)
    security: SecuritySettings | None = None
    record: RecordSettings = Field(default_factory=RecordSettings)
    serve: ServeSettings | None = None  # a cell service (vgr serve); vgr run refuses such a recipe
    stages: dict[str, StageSpec]

    @field_validator("vgr")
    @classmethod
    def _format(cls, v: int) -> int:
        if v != RECIPE_FORMAT:
            raise ValueError(f"recipe format {v} is not supported by this vgr (format {RECIPE_FORMAT})")
        return v

    @field_validator("name", "run_id")
    @classmethod
    def _names(cls, v: str | None) -> str | None:
        if v is not None and not NAME_RE.match(v):
            raise ValueError("use letters, digits, '_' and '-', starting with a letter (max 64)")
        return v

    @field_validator("stages")
    @classmethod
    def _stage_names(cls, v: dict[str, StageSpec]) -> dict[str, StageSpec]:
        if not v:
            raise ValueError("a recipe needs at least one stage")
        for name in v:
            if not NAME_RE.match(name):
                raise ValueError(f"stage name {name!r}: use letters, digits, '_' and '-', starting with a letter")
        return v

    def processes_used(self) -> list[str]:
        return sorted({s.process for s in self.stages.values()})

    def zenoh_for(self, process: str) -> ZenohSettings:
        base = self.zenoh.model_copy(deep=True)
        over = self.processes.get(process)
        if over is not None:
            if over.listen is not None:
                base.listen = list(over.listen)
            if over.connect is not None:
                base.connect = list(over.connect)
        return base


@dataclass
class LoadedRecipe:
    """A validated recipe with its source text and where each key came from."""

    recipe: Recipe
    text: str
    file: str | None
    locations: Locations
    overrides: list[str] = field(default_factory=list)
    data: dict[str, Any] = field(default_factory=dict)  # after overrides and vars, before validation
    overridden: dict[tuple[str | int, ...], str] = field(default_factory=dict)  # data path -> its -p text

    def problem(self, path: tuple[str | int, ...], message: str, suggestion: str | None = None) -> Problem:
        file, line, col = place(path, self.locations, self.file, self.overridden)
        return Problem(message, ".".join(map(str, path)), file, line, col, suggestion)

    @property
    def path(self) -> Path | None:
        return Path(self.file) if self.file else None


# --------------------------------------------------------------------------- overrides and vars


def _parse_scalar(text: str) -> Any:
    try:
        return yaml.safe_load(text) if text.strip() else ""
    except yaml.YAMLError:
        return text


COMMAND_LINE = "<command line>"


def place(
    path: tuple[str | int, ...], lr: Locations, file: str | None, overridden: dict[tuple[str | int, ...], str]
) -> tuple[str | None, int | None, int | None]:
    """Where the value at *path* came from: ``<command line> -p ...`` when an override set it (or a
    mapping above it), else its line and column in *file*."""
    for p, text in overridden.items():
        if path[: len(p)] == p:
            return f"{COMMAND_LINE} -p {text}", None, None
    line, col = locate(lr, path)
    return file, line, col


def apply_overrides(
    data: dict[str, Any],
    overrides: list[str],
    file: str | None,
    overridden: dict[tuple[str | int, ...], str] | None = None,
) -> list[Problem]:
    """Apply ``key.path=value`` overrides to raw recipe data in place; return problems found. Each
    value set is noted in *overridden* (its data path -> the override's text)."""
    overridden = {} if overridden is None else overridden
    problems: list[Problem] = []
    stages = data.get("stages") if isinstance(data.get("stages"), dict) else {}
    for ov in overrides:
        where = Problem("", key=f"-p {ov}", file="<command line>")
        if "=" not in ov:
            problems.append(Problem("override must look like stage.param=value", where.key, where.file))
            continue
        path_text, value_text = ov.split("=", 1)
        parts = [p for p in path_text.strip().split(".") if p]
        value = _parse_scalar(value_text)
        if not parts:
            problems.append(Problem("empty override key", where.key, where.file))
            continue
        if parts[0] in ("seed", "name", "clock", "run_id", "on_error", "rejoin") and len(parts) == 1:
            data[parts[0]] = value
            overridden[(parts[0],)] = ov
            continue
        if parts[0] == "vars" and len(parts) == 2:
            if not isinstance(data.get("vars"), dict):
                data["vars"] = {}
            data["vars"][parts[1]] = value
            continue
        stage = parts[0]
        if stage not in stages:
            problems.append(
                Problem(
                    f"no stage named {stage!r} to override",
                    where.key,
                    where.file,
                    suggestion=nearest(stage, [*stages, "vars", "seed"]),
                )
            )
            continue
        if len(parts) < 2:
            problems.append(Problem("override must name a parameter: stage.param=value", where.key, where.file))
            continue
        keys = parts[1:]
        if keys[0] == "params":
            keys = keys[1:]
        spec = stages[stage]
        if not isinstance(spec, dict):
            problems.append(Problem(f"stage {stage!r} is not a mapping", where.key, where.file))
            continue
        target = spec.setdefault("params", {})
        if not isinstance(target, dict):
            problems.append(Problem(f"stages.{stage}.params is not a mapping", where.key, where.file))
            continue
        for k in keys[:-1]:
            nxt = target.setdefault(k, {})
            if not isinstance(nxt, dict):
                problems.append(Problem(f"parameter {k!r} is not a mapping", where.key, where.file))
                break
            target = nxt
        else:
            target[keys[-1]] = value
            overridden[("stages", stage, "params", *keys)] = ov
    return problems


def substitute_vars(
    value: Any,
    variables: dict[str, Any],
    path: tuple[str | int, ...],
    lr: Locations,
    file: str | None,
    problems: list[Problem],
) -> Any:
    """Replace ``${name}`` references in strings (recursively); unknown names become problems."""
    if isinstance(value, dict):
        return {k: substitute_vars(v, variables, (*path, k), lr, file, problems) for k, v in value.items()}
    if isinstance(value, list):
        return [substitute_vars(v, variables, (*path, i), lr, file, problems) for i, v in enumerate(value)]
    if not isinstance(value, str) or "${" not in value:
        return value
    for name in _VAR_RE.findall(value):
        if name not in variables:
            line, col = locate(lr, path)
            problems.append(
                Problem(
                    f"unknown variable ${{{name}}}",
                    ".".join(map(str, path)),
                    file,
                    line,
                    col,
                    nearest(name, variables),
                )
            )
            return value
    whole = _VAR_RE.fullmatch(value)
    if whole:
        return variables[whole.group(1)]
    return _VAR_RE.sub(lambda m: str(variables[m.group(1)]), value)


# --------------------------------------------------------------------------- validation


def _fields_at(model: type[BaseModel], loc: tuple[Any, ...]) -> list[str]:
    """Field names valid at *loc* inside *model* (for 'did you mean' on unknown keys)."""
    current: Any = model
    for part in loc:
        if isinstance(current, type) and issubclass(current, BaseModel):
            f = current.model_fields.get(str(part))
            if f is None:
                return []
            current = f.annotation
        elif get_origin(current) is dict:
            current = get_args(current)[1]
        else:
            return []
    if isinstance(current, type) and issubclass(current, BaseModel):
        return list(current.model_fields)
    return []


def pydantic_problems(
    exc: ValidationError,
    model: type[BaseModel],
    prefix: tuple[str | int, ...],
    lr: Locations,
    file: str | None,
    overridden: dict[tuple[str | int, ...], str] | None = None,
) -> list[Problem]:
    """Turn a pydantic ValidationError into located problems with suggestions (at the command line's
    ``-p`` for a value an override set)."""
    out: list[Problem] = []
    for err in exc.errors():
        loc = tuple(err["loc"])
        path = (*prefix, *loc)
        file_of, line, col = place(path, lr, file, overridden or {})
        key = ".".join(map(str, path))
        etype = err["type"]
        if etype == "extra_forbidden" and loc:
            sugg = nearest(str(loc[-1]), _fields_at(model, loc[:-1]))
            out.append(Problem(f"unknown key {loc[-1]!r}", key, file_of, line, col, sugg))
        elif etype == "missing" and loc:
            out.append(Problem(f"missing required key {loc[-1]!r}", key, file_of, line, col))
        else:
            msg = err["msg"].removeprefix("Value error, ")
            out.append(Problem(f"{msg} (got {_short(err.get('input'))})", key, file_of, line, col))
    return out


def _short(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def load_recipe(
    source: str | Path, overrides: list[str] | None = None, *, text: str | None = None, base: Path | None = None
) -> LoadedRecipe:
    """Read, override, substitute and validate a recipe file (or *text*, named *source*).

    Each ``plugins:`` entry is resolved (engine.recipe.plugin_entries: an installed plugin's name or
    a plugin file's absolute path), files relative to *base* (default: the folder of *source*; a
    recording's recipe passes the folder it was run from). Raises RecipeError listing every problem with its location.
    """
    overrides = list(overrides or [])
    file = str(source)
    if text is None:
        p = Path(source)
        if not p.is_file():
            raise RecipeError([Problem(f"recipe file not found: {p}", file=file)])
        try:
            text = p.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise RecipeError([Problem(f"cannot read recipe: {exc}", file=file)]) from None
    data, locations = load_with_locations(text, file)
    if not isinstance(data, dict):
        got = "an empty file" if data is None else f"a {type(data).__name__}"
        raise RecipeError([Problem(f"a recipe must be a YAML mapping, got {got}", file=file, line=1)])
    overridden: dict[tuple[str | int, ...], str] = {}
    problems = apply_overrides(data, overrides, file, overridden)
    variables = data.get("vars") if isinstance(data.get("vars"), dict) else {}
    if isinstance(data.get("stages"), dict):
        data["stages"] = substitute_vars(data["stages"], variables, ("stages",), locations, file, problems)
    serve = data.get("serve")
    if isinstance(serve, dict) and isinstance(serve.get("gateways"), dict):  # e.g. a port or a ROS domain
        path = ("serve", "gateways")
        serve["gateways"] = substitute_vars(serve["gateways"], variables, path, locations, file, problems)
    if problems:
        raise RecipeError(problems)
    try:
        recipe = Recipe.model_validate(data)
    except ValidationError as exc:
        raise RecipeError(pydantic_problems(exc, Recipe, (), locations, file, overridden)) from None
    loaded = LoadedRecipe(recipe, text, file, locations, overrides, data, overridden)
    _check_plugins(loaded, base if base is not None else Path(file).resolve().parent)
    return loaded


def _check_plugins(loaded: LoadedRecipe, base: Path) -> None:
    """Every ``plugins:`` entry resolved to an installed plugin or a usable file, else RecipeError."""
    from engine.recipe.plugin_entries import PluginEntryError, resolve_plugin

    resolved, problems = [], []
    for i, entry in enumerate(loaded.recipe.plugins):
        try:
            resolved.append(resolve_plugin(entry, base))
        except PluginEntryError as exc:
            problems.append(loaded.problem(("plugins", i), str(exc)))
    if problems:
        raise RecipeError(problems)
    loaded.recipe.plugins = resolved
