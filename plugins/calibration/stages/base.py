"""What every calibration solver stage shares: sample buffers, when to solve, what to publish.

A subclass declares its data ports and their message types (``DATA_PORTS``; its ``inputs`` are those
plus the ``solve`` trigger port every solver has), and implements :meth:`CalibrationStage.calibrate`
(messages -> CalibrationResult, notes) and :meth:`CalibrationStage.transforms` (which estimated
transforms go downstream, with frame names).

* Messages of the data ports are kept in arrival order (per port: publication order); so are those of
  the side ports (``SIDE_PORTS``: what the samples are read with, such as a camera model), which are
  not samples and not counted as such.
* A message on ``solve`` calibrates from everything received so far; so does the end of all inputs
  (``finish``) when ``solve_on_finish`` and samples arrived since the last solve (or none was made).
  The engine orders messages within a port, not across ports, so a ``solve`` whose ``args`` carry
  ``total_samples`` (as ``calibration_poses``' ``done`` does) waits until every data port has
  received that many messages; if some never come (a missed detection), the end of input solves.
* Output ``result`` (CalibrationResultMsg: verdict, reasons, metrics, the full result as JSON) is
  published every time. Output ``transform`` carries the calibrated transforms **only when the
  verdict is usable** (ok / warning): a degenerate or failed calibration never goes downstream as a
  transform (DESIGN safety rule); it raises a ``warning`` event with the reasons instead.
* Each transform goes from a frame the cell already has (the robot's ``base`` or ``tcp``, the
  instrument's or tracker's frame: taken from the messages or named by a parameter) to the frame it
  estimates. An estimate of a frame the cell's stages publish themselves (the camera, the robot base,
  the tracker on the tool) gets a name of its own, ``<frame>_calibrated`` by default
  (:func:`calibrated`): one frame with two parents is not a tree, and a 3D view of the recording then
  shows the estimate beside the frame it estimates.
* Bad input (unpaired samples, NaN, too few samples, mixed units) does not raise: it becomes a
  ``failed`` result whose reason starts with "bad input".
* Results are stamped with the newest sample's stamp, so a replay reproduces them exactly.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field

from engine.files import replace_text
from engine.messages import CalibrationResultMsg, Message, Request, Transform
from engine.stage import Stage, StageParams
from plugins.calibration.inputs import PairingOptions
from plugins.calibration.result import CalibrationResult

SOLVE_PORT = "solve"
CALIBRATED = "_calibrated"


def calibrated(frame: str) -> str:
    """The default name of the estimate of *frame* (``camera`` -> ``camera_calibrated``)."""
    return frame + CALIBRATED


class PairingParams(StageParams):
    """Parameters every calibration stage has: pairing of its two sample streams, when to solve."""

    pair: Literal["stamp", "order"] = Field("stamp", description="pair samples by nearest stamp or by order")
    max_skew_s: float | None = Field(0.05, ge=0.0, description="largest stamp difference within a pair")
    drop_unmatched: bool = Field(True, description="drop samples without a partner (a warning) instead of failing")
    solve_on_finish: bool = Field(True, description="calibrate when all inputs have ended")


def result_message(result: CalibrationResult, stamp_ns: int) -> CalibrationResultMsg:
    """The wire form of *result*; its named transforms are included only when the result is usable."""
    transforms = (
        {k: v for k, v in result.estimate.items() if isinstance(v, np.ndarray) and v.shape == (4, 4)}
        if result.usable
        else {}
    )
    metrics = {k: float(v) for k, v in result.metrics.items() if isinstance(v, int | float)}
    return CalibrationResultMsg(
        kind=result.kind,
        verdict=result.verdict,
        method=result.method,
        reasons=list(result.reasons),
        transforms=transforms,
        metrics=metrics,
        result_json=result.to_json(),
        stamp_ns=stamp_ns,
    )


class CalibrationStage(Stage):
    """Base of the calibration solver stages (see the module docstring)."""

    role = "solver"
    KIND: ClassVar[str] = ""
    DATA_PORTS: ClassVar[dict[str, type[Message]]] = {}
    SIDE_PORTS: ClassVar[dict[str, type[Message]]] = {}
    outputs: ClassVar = {"result": CalibrationResultMsg, "transform": Transform}
    Params: ClassVar[type[StageParams]] = PairingParams

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls.inputs = {**cls.DATA_PORTS, **cls.SIDE_PORTS, SOLVE_PORT: Request}

    def setup(self) -> None:
        self.buffers: dict[str, list[Any]] = {p: [] for p in self.DATA_PORTS}
        self.side: dict[str, list[Any]] = {p: [] for p in self.SIDE_PORTS}
        self._new_samples = False
        self._waiting: tuple[int, str] | None = None  # a solve waiting for (samples per port, why)
        self.solves = 0
        self.last_result: CalibrationResult | None = None

    def on_message(self, port: str, msg: Message) -> None:
        if port == SOLVE_PORT:
            why = f"solve trigger {msg.seq}"
            total = getattr(msg, "args", {}).get("total_samples")
            if isinstance(total, int) and not self._have(total):
                self._waiting = (total, why)
            else:
                self._solve(why)
            return
        if port in self.side:
            self.side[port].append(msg)
            return
        self.buffers[port].append(msg)
        self._new_samples = True
        if self._waiting is not None and self._have(self._waiting[0]):
            self._solve(self._waiting[1])

    def _have(self, n: int) -> bool:
        return all(len(b) >= n for b in self.buffers.values())

    def finish(self) -> None:
        p: PairingParams = self.params  # type: ignore[assignment]
        if self._waiting is not None or (p.solve_on_finish and (self._new_samples or self.solves == 0)):
            self._solve(self._waiting[1] + ", at the end of input" if self._waiting else "end of input")
        if self.last_result is not None:  # the answer, printed at the end of the run, kept in the run folder
            r = self.last_result
            files = {}
            if (folder := self.ctx.output_dir()) is not None:
                files["result"] = str(replace_text(folder / "result.json", r.to_json(indent=1) + "\n"))
            self.ctx.event("result", f"{self.KIND}_result", result_text(r), verdict=r.verdict, files=files)

    def pairing(self) -> PairingOptions:
        p: PairingParams = self.params  # type: ignore[assignment]
        return {"mode": p.pair, "max_skew_s": p.max_skew_s, "drop_unmatched": p.drop_unmatched}

    def streams(self) -> list[list[Any]]:
        """The messages received on each data port, in ``DATA_PORTS`` order."""
        return [self.buffers[p] for p in self.DATA_PORTS]

    def frame_of(self, port: str, default: str) -> str:
        """The frame the first message on *port* names, else *default*."""
        return self.buffers[port][0].frame_id or default

    # -- subclass API --------------------------------------------------------------------------
    def calibrate(self) -> tuple[CalibrationResult, list[str]]:
        """Calibrate from ``self.buffers``; returns the result and notes about the input.
        Raise ValueError for bad input (it becomes a failed result)."""
        raise NotImplementedError

    def transforms(self, result: CalibrationResult) -> list[tuple[np.ndarray, str, str]]:
        """(T_parent_child, parent frame, child frame) of each transform to publish when usable."""
        return []

    def extra_outputs(self, result: CalibrationResult, stamp_ns: int) -> None:
        """Hook for subclass-specific artefacts (reports) after a solve."""

    # -- solving -------------------------------------------------------------------------------
    def _stamp(self) -> int:
        stamps = [m.stamp_ns for msgs in self.buffers.values() for m in msgs]
        return max(stamps, default=0)

    def _solve(self, why: str) -> None:
        self._new_samples = False
        self._waiting = None
        self.solves += 1
        counts = {p: len(m) for p, m in self.buffers.items()}
        try:
            result, notes = self.calibrate()
        except ValueError as exc:
            result = CalibrationResult(
                kind=self.KIND,
                verdict="failed",
                reasons=[f"bad input: {exc}"],
                advice=["check the wiring and the samples (see the reason)"],
                metrics={f"n_{p}": float(n) for p, n in counts.items()},
            )
            notes = []
        for note in notes:
            self.ctx.event("warning", "calibration_input", note)
        stamp = self._stamp()
        self.last_result = result
        self.ctx.publish("result", result_message(result, stamp))
        if result.usable:
            for T, parent, child in self.transforms(result):
                self.ctx.publish("transform", Transform(frame_id=parent, child_frame_id=child, T=T, stamp_ns=stamp))
            self.ctx.event(
                "info",
                "calibrated",
                f"{self.KIND} calibration ({why}): verdict {result.verdict}",
                verdict=result.verdict,
                samples=counts,
            )
        else:
            self.ctx.event(
                "warning",
                "calibration_unusable",
                f"{self.KIND} calibration ({why}) is {result.verdict}, no transform published: "
                + "; ".join(result.reasons[:3]),
                verdict=result.verdict,
                reasons=result.reasons,
                advice=result.advice,
                samples=counts,
            )
        self.extra_outputs(result, stamp)


def result_text(result: CalibrationResult) -> str:
    """The answer at the end of a run: kind and verdict, then one line per estimate with its 1-sigma
    (mm, deg), then why when it is not ok."""
    lines = [f"{result.kind.replace('_', '-')} calibration: verdict {result.verdict}"]
    lines += [
        f"  {r.name} = {r.value:.3f}" + ("" if r.sigma is None else f" ± {r.sigma:.3f}") + f" {r.unit}"
        for r in result.summary_rows()
    ]
    if result.verdict != "ok" and result.reasons:
        lines += [f"  because: {reason}" for reason in result.reasons[:3]]
    return "\n".join(lines)
