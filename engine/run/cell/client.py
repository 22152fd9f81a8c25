"""A small client of the cell-service API, for controllers and scripts written in Python.

::

    from engine.run.cell.client import CellClient
    with CellClient("sim") as cell:                      # the service of this user on this host
        reply = cell.locate(pose=T_base_flange)          # a 4x4 (metres); a fresh request id
        if reply["status"] == "ok":
            correction = reply["result"]["parts"][0]["correction"]

Each call returns the reply document (engine.run.cell.protocol) as it came. A cell on another host
is reached with ``connect=["tcp/10.0.0.5:7447"]`` (and ``certs``/``identity`` when the recipe has a
``security:`` block). :class:`CellUnreachableError` says that no service answered: the cell is not
running, or not reachable from here. Request ids: ``new_id()`` gives a fresh one; pass the same id
again to repeat a request safely (the service answers it again without a second cycle).
"""

from __future__ import annotations

import json
import secrets
import time
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from engine.recipe.model import ZenohSettings
from engine.run.cell import protocol
from engine.transport.bus import Bus
from engine.transport.endpoints import run_sockets


class CellUnreachableError(RuntimeError):
    """No cell service answered (not running, not reachable, or not within the timeout)."""


def new_id(prefix: str = "req") -> str:
    """A request id no other request of this client had (random, 48 bits)."""
    return f"{prefix}-{secrets.token_hex(6)}"


class CellClient:
    """The API of cell *cell*: on this host's private socket of that cell unless *connect* names endpoints."""

    def __init__(
        self,
        cell: str,
        *,
        connect: list[str] | None = None,
        timeout_s: float = 30.0,
        certs: str | None = None,
        identity: str | None = None,
        connect_timeout_s: float = 5.0,
    ) -> None:
        self.cell = cell
        self.timeout_s = timeout_s
        endpoints = list(connect or run_sockets(cell))
        if not endpoints:
            raise CellUnreachableError(
                f"no cell {cell!r} on this host: start it with `vgr serve RECIPE` (its serve.cell), "
                "or name its endpoint with --connect"
            )
        extra = None
        if certs is not None:  # mutual TLS as *identity*, a controller the recipe's security block admits
            from engine.security.tls import folder_identity, tls_entries

            if identity is None:
                raise CellUnreachableError("certs need an identity: the controller certificate's name")
            extra = tls_entries(folder_identity(Path(certs), identity))
        try:
            self._bus: Bus = Bus(ZenohSettings(listen=[], connect=endpoints), extra)
        except Exception as exc:
            raise CellUnreachableError(f"cannot reach cell {cell!r} at {', '.join(endpoints)}: {exc}") from exc
        if not self._serving(connect_timeout_s):
            self._bus.close()
            raise CellUnreachableError(
                f"cell {cell!r} is not serving at {', '.join(endpoints)} (no answer within {connect_timeout_s:g} s)"
            )

    def _serving(self, timeout_s: float) -> bool:
        """True once the cell's serving token is seen (the session's links come up first), within *timeout_s*."""
        deadline = time.monotonic() + timeout_s
        while True:
            if self._bus.alive(protocol.alive_key(self.cell), timeout_s=0.5):
                return True
            if time.monotonic() > deadline:
                return False
            time.sleep(0.05)

    def __enter__(self) -> CellClient:
        return self

    def __exit__(self, *exc: object | TracebackType) -> None:
        self.close()

    def close(self) -> None:
        self._bus.close()

    def call(self, command: str, request: dict[str, Any] | None = None) -> dict[str, Any]:
        """Send *request* (a document; ``api`` filled in, and a fresh ``id`` for a job command without
        one) and return the reply document."""
        doc = {"api": protocol.API_VERSION, **(request or {})}
        if command in protocol.JOB_COMMANDS and "id" not in doc:
            doc["id"] = new_id(command)
        return self.call_raw(command, protocol.encode(doc))

    def call_raw(self, command: str, payload: bytes) -> dict[str, Any]:
        """Send *payload* as it is (e.g. a malformed request, for a test) and return the reply."""
        key = protocol.api_key(self.cell, command)
        try:
            answers = self._bus.request(key, payload, b"", self.timeout_s)
        except TimeoutError:
            raise CellUnreachableError(
                f"cell {self.cell!r}: no reply to {command} within {self.timeout_s:g} s"
            ) from None
        except LookupError:
            raise CellUnreachableError(f"cell {self.cell!r} does not answer {command} (is it serving?)") from None
        answer = answers[0]
        if answer.error is not None:
            raise CellUnreachableError(f"cell {self.cell!r}: {command} failed: {answer.error}")
        reply = json.loads(answer.payload)
        if not isinstance(reply, dict):
            raise CellUnreachableError(f"cell {self.cell!r}: {command} replied {type(reply).__name__}, not a document")
        return reply

    # -- the commands ----------------------------------------------------------------------------
    def locate(
        self, pose: np.ndarray | None = None, *, count: int = 1, request_id: str | None = None
    ) -> dict[str, Any]:
        doc: dict[str, Any] = {"id": request_id or new_id("locate"), "count": count}
        if pose is not None:
            doc["pose"] = protocol.pose_doc(np.asarray(pose, dtype=float))
        return self.call("locate", doc)

    def guide(
        self, pose: np.ndarray, step: int, start_pose: np.ndarray | None = None, *, request_id: str | None = None
    ) -> dict[str, Any]:
        doc: dict[str, Any] = {"id": request_id or new_id("guide"), "step": step, "pose": protocol.pose_doc(pose)}
        if start_pose is not None:
            doc["start_pose"] = protocol.pose_doc(start_pose)
        return self.call("guide", doc)

    def status(self) -> dict[str, Any]:
        return self.call("status")

    def reload(self, changes: dict[str, Any] | None = None) -> dict[str, Any]:
        return self.call("reload", {"set": changes or {}})

    def stop(self) -> dict[str, Any]:
        return self.call("stop")
