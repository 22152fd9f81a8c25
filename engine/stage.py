"""What a stage is: typed ports, parameters, services, and the context the engine hands it.

A stage type is a subclass of :class:`Stage` that declares

* ``type_name``  the name recipes use (``type: transform_cloud``),
* ``inputs`` / ``outputs``  port name -> message class (typed ports, checked before a run),
* ``services``  services it answers (name -> :class:`ServiceSpec`), and ``uses``: services of
  other stages it calls, wired in the recipe like inputs (``uses: {robot: sim_robot.move}``),
* ``Params``  a pydantic model of its parameters (unknown keys are errors),
* ``role``  source | sensor | device | solver | action | transform | sink — replay re-runs every
  stage except sources, sensors and devices (robots), which it feeds from the recording.

The engine guarantees: ``on_message`` and ``on_request`` of one stage are never called
concurrently, and messages of one input port arrive in publication order. A message published
without ``stamp_ns`` gets the stamp of the input being handled (causal time), or the clock's time
when published from ``run()``; so outputs do not depend on when a handler happened to run, and a
replay reproduces them bit for bit. Stages read time only through ``ctx.clock``. ``run`` (sources only)
runs on the stage's own thread; it must return when the input ends or ``ctx.stopping`` is set.
Every stage has an implicit ``events`` output carrying :class:`~engine.messages.Event`.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Literal, get_args, get_origin

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from pydantic_core import PydanticUndefined

from engine import run_folder
from engine.messages import Message

if TYPE_CHECKING:
    from engine.clock import Clock

Role = Literal["source", "sensor", "device", "solver", "action", "transform", "sink"]
PLAYBACK_ROLES: frozenset[str] = frozenset({"source", "sensor", "device"})  # replay feeds these from the file
EVENTS_PORT = "events"


def stage_rng(seed: int, stage: str) -> np.random.Generator:
    """The random generator of *stage* in a run with *seed* (the same in a run and its replay)."""
    import zlib

    return np.random.default_rng([seed & 0xFFFFFFFF, zlib.crc32(stage.encode())])


class StageParams(BaseModel):
    """Base of every stage's parameter model: unknown keys are rejected, values validated, inf and NaN refused."""

    # inf and NaN refused: an infinite limit or rate is no limit (a limit may be absent, never infinite)
    model_config = ConfigDict(extra="forbid", frozen=True, arbitrary_types_allowed=True, allow_inf_nan=False)


INPUT_FILE_MARK = "vgr_input_file"


def input_file(default: Any = PydanticUndefined, *, description: str) -> Any:
    """A parameter naming a file or folder the stage reads (relative: to the recipe's folder, see
    :func:`resolve_input`). ``vgr validate`` and ``vgr run`` refuse a recipe whose input file does not
    exist before anything starts (engine.graph.missing_input_files)."""
    return Field(default, description=description, json_schema_extra={INPUT_FILE_MARK: True})


def resolve_input(value: str | Path, recipe_dir: Path | None) -> Path:
    """An input file's path: *value* as given when absolute or without a recipe folder, else inside it."""
    path = Path(value).expanduser()
    return path if path.is_absolute() or recipe_dir is None else recipe_dir / path


@dataclass(frozen=True)
class ServiceSpec:
    """A request/reply service: request and reply message classes and a one-line description.

    In a stage's ``uses``, ``optional=True`` means the recipe may leave the client unwired.
    """

    request: type[Message]
    reply: type[Message]
    doc: str = ""
    optional: bool = False


class ServiceError(RuntimeError):
    """A service call failed: the provider raised, refused, or no provider answered."""


class ServiceTimeoutError(ServiceError):
    """No reply within the timeout."""


class RunStoppingError(Exception):
    """The run is stopping (Ctrl-C, a failure, a stop request): ``ctx.call`` sends no new request, and
    a call already waiting for its reply returns at once with this error (the provider may still be
    working on it; its reply is not awaited). A stage that lets it escape ends quietly: the stop, not
    the stage, is what happened.

    Deliberately not a :class:`ServiceError`: what a stage does about a failed call (an alarm, a
    skipped pose, a retry, a fallback) is not what a stop calls for, so ``except ServiceError`` lets
    it through and the stage ends at once."""


class StageContext:
    """The engine's side of a stage: publish, call services, raise events, read the clock.

    Implemented by the runner (engine.run.runtime), the replay and a detached context; stages only use
    this interface.
    """

    name: str
    run_id: str
    seed: int
    rng: np.random.Generator
    clock: Clock
    log: logging.Logger
    recipe_dir: Path | None = None  # folder of the recipe file: relative paths in parameters start here
    run_dir: Path | None = None  # this run's folder (engine.run_folder); None when used as a library

    def __init__(
        self, name: str, run_id: str, seed: int, clock: Clock, log: logging.Logger, recipe_dir: Path | None
    ) -> None:
        """The identity of stage *name* in run *run_id*; its random generator follows from *seed*
        and its name, the same in a run, its replay and a detached run."""
        self.name, self.run_id, self.seed = name, run_id, seed
        self.rng = stage_rng(seed, name)
        self.clock, self.log, self.recipe_dir = clock, log, recipe_dir
        self._output_dirs: dict[str, Path | None] = {}

    def input_path(self, value: str | Path) -> Path:
        """The file or folder an :func:`input_file` parameter names (relative: to the recipe's folder)."""
        return resolve_input(value, self.recipe_dir)

    def files_in_run(self, details: dict[str, Any]) -> dict[str, Any]:
        """*details* of an event with its ``files`` named relative to the run folder when inside it."""
        files = details.get("files")
        if files and self.run_dir is not None:
            details["files"] = {k: run_folder.relative(self.run_dir, v) for k, v in files.items()}
        return details

    def output_dir(self, named: str | Path | None = None) -> Path | None:
        """The folder this stage writes its files in (created on first use), or None for none.

        *named* is the stage's own parameter (e.g. ``report_dir``): unset, the stage's folder in the
        run folder; relative, a folder inside the run folder; absolute, the user's new or empty
        folder (engine.run_folder.output_dir says the rules; OutputDirError when they are broken)."""
        key = "" if named is None else str(named)
        if key not in self._output_dirs:
            self._output_dirs[key] = run_folder.output_dir(self.run_dir, self.name, named)
        return self._output_dirs[key]

    def output_file(self, named: str | Path) -> Path:
        """The path of the file a parameter of this stage names (e.g. ``output``), to create with
        engine.files.create_new: relative, inside the run folder; absolute, a new file of the user's
        (engine.run_folder.output_file; OutputDirError when it exists)."""
        return run_folder.output_file(self.run_dir, self.name, named)

    def publish(self, port: str, msg: Message) -> None:
        """Publish *msg* on output *port* (seq and, if unset, stamp are filled in)."""
        raise NotImplementedError

    def loan(self, port: str, shape: int | tuple[int, ...], dtype: Any = np.uint8) -> np.ndarray:
        """A writable array to fill and publish on output *port* as a message's bulk array (a point
        cloud's points, a depth image). Where the port's consumers read it as a view of shared
        memory (engine.transport.shm_views), the array is already there: the message goes out
        without a copy. Elsewhere (in this process only, a recording, another host, a replay) it is
        a plain ``numpy.empty``. Either way, do not write into it after publishing it."""
        return np.empty(shape, dtype=dtype)

    def call(self, client: str, request: Message, timeout_s: float = 10.0) -> Message:
        """Call the service wired to *client* in the recipe's ``uses`` and wait for its reply
        (:class:`ServiceError` if it fails, :class:`RunStoppingError` once the run stops)."""
        raise NotImplementedError

    def has_client(self, client: str) -> bool:
        """True when the recipe wired the service client *client* (optional clients may be unwired)."""
        raise NotImplementedError

    def event(self, level: str, code: str, message: str, **details: Any) -> None:
        """Publish an Event (debug/info/result/warning/error/alarm) on this stage's ``events`` port.

        ``result`` is the stage's report for people (kept in the run summary, printed by ``vgr run``);
        ``details["files"]`` may name the files it wrote ({label: path}); those in the run folder are
        recorded relative to it, so a run and its replay name them alike."""
        raise NotImplementedError

    @property
    def stopping(self) -> bool:
        """True once the run is stopping (end of input elsewhere, Ctrl-C, a failure)."""
        raise NotImplementedError

    def sleep(self, seconds: float) -> bool:
        """Sleep on the run's clock; returns False (early) when the run is stopping."""
        raise NotImplementedError


class Stage:
    """Base class of every stage type. Subclass it, declare ports/params, implement handlers."""

    type_name: ClassVar[str] = ""
    role: ClassVar[Role] = "transform"
    inputs: ClassVar[Mapping[str, type[Message]]] = {}
    outputs: ClassVar[Mapping[str, type[Message]]] = {}
    services: ClassVar[Mapping[str, ServiceSpec]] = {}
    uses: ClassVar[Mapping[str, ServiceSpec]] = {}
    Params: ClassVar[type[StageParams]] = StageParams

    def __init__(self, ctx: StageContext, params: StageParams) -> None:
        self.ctx = ctx
        self.params = params

    # -- lifecycle -------------------------------------------------------------------------
    def setup(self) -> None:
        """Called once the bus is up and every stage of the run is ready, before any message."""

    def run(self) -> None:
        """Sources only: produce messages until done (return) or ``ctx.stopping``."""

    def on_message(self, port: str, msg: Message) -> None:
        """Handle one message from input *port*."""

    def on_request(self, service: str, request: Message) -> Message:
        """Answer a request to one of ``services``; raise to return an error to the caller."""
        raise NotImplementedError(f"{self.type_name} declares service {service!r} but does not answer it")

    def finish(self) -> None:
        """All inputs have ended: flush what is pending (outputs still open)."""

    def halt(self) -> None:
        """The run stops early (Ctrl-C, a failed stage, a stop request): stop the motion of the device
        this stage drives, now. Called once, on the runner's thread, before the stages' threads are
        joined and before ``teardown``; it must return quickly. Device stages override it."""

    def teardown(self) -> None:
        """Always called last, also after a failure; release devices here."""

    # -- introspection ---------------------------------------------------------------------
    @classmethod
    def is_source(cls) -> bool:
        return cls.run is not Stage.run

    @classmethod
    def summary(cls) -> str:
        doc = (cls.__doc__ or "").strip()
        return doc.splitlines()[0] if doc else ""

    @classmethod
    def all_outputs(cls) -> dict[str, type[Message]]:
        """Declared outputs plus the implicit ``events`` port (computed once per class)."""
        cached = cls.__dict__.get("_all_outputs_cache")
        if cached is None:
            from engine.messages import Event

            cached = {**cls.outputs, EVENTS_PORT: Event}
            cls._all_outputs_cache = cached  # type: ignore[attr-defined]
        return cached

    @classmethod
    def describe(cls) -> dict[str, Any]:
        """Ports, services and parameters (with defaults and types) for ``vgr plugins``."""
        params = {}
        for name, f in cls.Params.model_fields.items():
            params[name] = {
                "type": _type_name(f.annotation),
                "required": f.is_required(),
                "default": None if f.is_required() else _jsonable(f.get_default(call_default_factory=True)),
                "description": f.description or "",
            }
        return {
            "type": cls.type_name,
            "role": cls.role,
            "summary": cls.summary(),
            "module": cls.__module__,
            "inputs": {k: v.TYPE for k, v in cls.inputs.items()},
            "outputs": {k: v.TYPE for k, v in cls.all_outputs().items()},
            "services": {k: f"{v.request.TYPE} -> {v.reply.TYPE}" for k, v in cls.services.items()},
            "uses": {k: f"{v.request.TYPE} -> {v.reply.TYPE}" for k, v in cls.uses.items()},
            "params": params,
        }


def _type_name(t: Any) -> str:
    if t is None:
        return "None"
    if get_origin(t) is Literal:
        return " | ".join(repr(a) for a in get_args(t))
    return getattr(t, "__name__", None) or str(t).replace("typing.", "")


def _jsonable(v: Any) -> Any:
    if isinstance(v, BaseModel):
        return v.model_dump()
    if isinstance(v, tuple | list):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v
