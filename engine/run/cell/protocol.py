"""The controller API of a cell service, version 1: commands, keys, request and reply documents.

Every command is a zenoh queryable ``vgr/<cell>/api/<command>`` taking one JSON object (UTF-8) and
answering one JSON object; the TCP gateway carries the same commands as text lines
(plugins.actions.cell.tcp_gateway). JSON Schemas of every document are in
``engine/run/cell/schemas/cell_api.schema.json``; docs/cell_service.md explains them.

A request::

    {"api": 1, "id": "part-0017", ...the command's fields}

``id`` (1-64 characters of letters, digits and ``_ . : -``) names the request: a job command
(``locate``, ``guide``) sent again with an id the service has answered gets the same reply again,
never a second capture or move (the service keeps the last ``serve.remember`` replies).

A reply::

    {"api": 1, "cell": "sim", "command": "locate", "id": "part-0017", "status": "ok", "code": 0,
     "message": "...", "cycle": 17, "result": {...}, "timing_ms": {...}}

``status``/``code`` come from engine.run.cell.codes; ``cycle`` is the number of the job that
answered (0 when none ran: ``busy``, ``invalid_request``, ``status``, ...); ``result`` is the
command's own (its schema is the command's); ``timing_ms`` says where the cycle's time went.

Poses travel as ``{"xyz_m": [x, y, z], "quat_xyzw": [x, y, z, w]}`` or ``{"matrix": 4x4}`` (metres);
:func:`pose_from_doc` checks them (finite, a unit quaternion, a rigid transform) and
:func:`pose_doc` writes them. Robot-vendor formats are converted at the TCP gateway, not here.
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

import numpy as np

from engine.run.cell.codes import Status, code_of
from engine.transforms import T_from_pose7, as_transform, pose7_from_T

API_VERSION = 1
JOB_COMMANDS = ("locate", "guide")  # run a cycle through the recipe's stages
SERVICE_COMMANDS = ("status", "reload", "stop")  # answered by the service itself
COMMANDS = JOB_COMMANDS + SERVICE_COMMANDS
REQUEST_ID_RE = re.compile(r"^[A-Za-z0-9_.:-]{1,64}$")
MAX_REQUEST_BYTES = 64 * 1024  # a request is a few hundred bytes; anything this big is not one


class InvalidRequest(ValueError):  # noqa: N818 - answered as the status invalid_request
    """A request the service cannot take (answered ``invalid_request`` with this message)."""


def schema() -> dict[str, Any]:
    """The JSON Schema of every request and reply (``$defs``: ``<command>_request``, ``reply``)."""
    from importlib import resources

    return json.loads(resources.files("engine.run.cell").joinpath("schemas/cell_api.schema.json").read_text())


def api_key(cell: str, command: str) -> str:
    """The zenoh key of *command* of cell *cell*."""
    return f"vgr/{cell}/api/{command}"


def alive_key(cell: str) -> str:
    """The liveliness token a serving cell declares: a client waits for it before its first request."""
    return f"vgr/{cell}/api/_serving"


def parse_request(command: str, payload: bytes) -> dict[str, Any]:
    """The request document of *command* from its *payload*, its envelope checked (InvalidRequest)."""
    if command not in COMMANDS:
        raise InvalidRequest(f"unknown command {command!r}: the API has {', '.join(COMMANDS)}")
    if len(payload) > MAX_REQUEST_BYTES:
        raise InvalidRequest(f"request of {len(payload)} bytes: at most {MAX_REQUEST_BYTES}")
    try:
        text = payload.decode("utf-8", errors="strict") if payload else "{}"
        doc = json.loads(text, parse_constant=_no_constant)
    except (ValueError, UnicodeDecodeError) as exc:
        raise InvalidRequest(f"the request is not JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise InvalidRequest(f"the request must be a JSON object, got {type(doc).__name__}")
    api = doc.get("api", API_VERSION)
    if api != API_VERSION:
        raise InvalidRequest(f"api {api!r}: this service speaks api {API_VERSION}")
    rid = doc.get("id")
    if command in JOB_COMMANDS and rid is None:
        raise InvalidRequest(f"{command} needs an 'id' (a repeated request is recognised by it)")
    if rid is not None and (not isinstance(rid, str) or not REQUEST_ID_RE.match(rid)):
        raise InvalidRequest(f"id {rid!r}: 1-64 characters of letters, digits and _ . : -")
    return doc


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number")


def reply_doc(
    cell: str,
    command: str,
    request_id: str | None,
    status: str,
    message: str,
    *,
    cycle: int = 0,
    result: dict[str, Any] | None = None,
    timing_ms: dict[str, float] | None = None,
) -> dict[str, Any]:
    """A reply document (see the module docstring)."""
    return {
        "api": API_VERSION,
        "cell": cell,
        "command": command,
        "id": request_id,
        "status": status,
        "code": code_of(status),
        "message": message,
        "cycle": cycle,
        "result": result or {},
        "timing_ms": timing_ms or {},
    }


def encode(doc: dict[str, Any]) -> bytes:
    """A document as the API sends it: compact JSON, finite numbers only."""
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()


def invalid(cell: str, command: str, request_id: Any, message: str) -> dict[str, Any]:
    """The reply to a request that could not be taken."""
    rid = request_id if isinstance(request_id, str) and REQUEST_ID_RE.match(request_id) else None
    return reply_doc(cell, command, rid, Status.invalid_request.name, message)


# -- poses ---------------------------------------------------------------------------------------
def pose_from_doc(doc: Any, name: str = "pose") -> np.ndarray:
    """The 4x4 transform of a pose document (InvalidRequest naming *name* when it is not one)."""
    if not isinstance(doc, dict):
        raise InvalidRequest(f"{name}: a pose is an object with xyz_m and quat_xyzw, or matrix")
    try:
        if "matrix" in doc:
            if set(doc) != {"matrix"}:
                raise InvalidRequest(f"{name}: give either matrix or xyz_m and quat_xyzw")
            M = np.array(doc["matrix"], dtype=float)
            if M.shape != (4, 4):
                raise InvalidRequest(f"{name}.matrix: 4 rows of 4 numbers, got shape {M.shape}")
            return as_transform(M, name=name, tol=1e-5)
        if set(doc) != {"xyz_m", "quat_xyzw"}:
            raise InvalidRequest(f"{name}: needs exactly xyz_m and quat_xyzw (or matrix), got {sorted(doc)}")
        xyz = np.array(doc["xyz_m"], dtype=float)
        q = np.array(doc["quat_xyzw"], dtype=float)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, InvalidRequest):
            raise
        raise InvalidRequest(f"{name}: {exc}") from None
    if xyz.shape != (3,) or q.shape != (4,):
        raise InvalidRequest(f"{name}: xyz_m has 3 numbers and quat_xyzw 4")
    if not (np.all(np.isfinite(xyz)) and np.all(np.isfinite(q))):
        raise InvalidRequest(f"{name}: not finite")
    norm = float(np.linalg.norm(q))
    if not math.isclose(norm, 1.0, abs_tol=1e-3):
        raise InvalidRequest(f"{name}: quat_xyzw has norm {norm:.6f}, not a unit quaternion")
    return T_from_pose7(xyz, q / norm)


def pose_doc(T: np.ndarray) -> dict[str, list[float]]:
    """The pose document of *T* (quaternion with w >= 0, as pose7_from_T gives it: one rotation, one document)."""
    xyz, q = pose7_from_T(T)
    return {"xyz_m": [float(v) for v in xyz], "quat_xyzw": [float(v) for v in q]}
