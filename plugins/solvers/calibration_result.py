"""The common result of every calibration solver (hand-eye, robot-world, Vive desk, TCP, kinematic).

A calibration is only useful when a user can act on it, so every solver returns the same shape:
the estimate, its covariance, per-sample residuals, outlier flags and a verdict with reasons.
Units are SI inside (m, rad); :meth:`CalibrationResult.summary_rows` renders mm / degrees for people.

Verdicts
--------
``ok``          estimate usable as is.
``warning``     usable, but something deserves attention (listed in ``reasons``).
``degenerate``  the data cannot determine the unknowns (e.g. all rotations about one axis);
                ``advice`` says which poses to add. Never use the estimate for robot motion.
``failed``      no trustworthy estimate (bad input, no convergence, residuals far above noise).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

Verdict = Literal["ok", "warning", "degenerate", "failed"]
USABLE_VERDICTS: frozenset[str] = frozenset({"ok", "warning"})


@dataclass
class CalibrationResult:
    """Estimate + uncertainty + diagnostics of one calibration.

    ``estimate`` maps names to values in SI units: 4x4 transforms are named ``T_a_b`` after the
    frame convention; scalars and vectors are allowed. ``param_names`` orders the parameter vector
    that ``covariance`` refers to (for a transform: its 6 tangent coordinates ``(v, w)`` with the
    perturbation documented by the solver, e.g. ``T_tcp_cam.vx`` ... ``T_tcp_cam.wz``).
    ``residuals`` is (n_samples, k) with ``residual_names`` naming the k columns (SI units).
    """

    kind: str
    verdict: Verdict
    estimate: dict[str, Any] = field(default_factory=dict)
    param_names: list[str] = field(default_factory=list)
    covariance: np.ndarray | None = None
    residuals: np.ndarray | None = None
    residual_names: list[str] = field(default_factory=list)
    outliers: np.ndarray | None = None
    reasons: list[str] = field(default_factory=list)
    advice: list[str] = field(default_factory=list)
    metrics: dict[str, float] = field(default_factory=dict)
    method: str = ""
    iterations: int = 0

    @property
    def usable(self) -> bool:
        """True when the estimate may drive a robot (verdict ok or warning)."""
        return self.verdict in USABLE_VERDICTS

    def std(self) -> dict[str, float]:
        """One-sigma standard deviation of each parameter (SI units), from the covariance."""
        if self.covariance is None:
            return {}
        sd = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        return dict(zip(self.param_names, sd.tolist(), strict=True))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (numpy arrays become nested lists)."""

        def conv(x: Any) -> Any:
            if isinstance(x, np.ndarray):
                return x.tolist()
            if isinstance(x, np.generic):
                return x.item()
            if isinstance(x, dict):
                return {k: conv(v) for k, v in x.items()}
            if isinstance(x, list | tuple):
                return [conv(v) for v in x]
            return x

        return conv(
            {
                "kind": self.kind,
                "verdict": self.verdict,
                "method": self.method,
                "iterations": self.iterations,
                "estimate": self.estimate,
                "param_names": self.param_names,
                "covariance": self.covariance,
                "residuals": self.residuals,
                "residual_names": self.residual_names,
                "outliers": self.outliers,
                "reasons": self.reasons,
                "advice": self.advice,
                "metrics": self.metrics,
            }
        )

    def to_json(self, **kwargs: Any) -> str:
        return json.dumps(self.to_dict(), **kwargs)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CalibrationResult:
        """Inverse of :meth:`to_dict` (lists that were arrays become arrays again)."""

        def arr(x: Any) -> np.ndarray | None:
            return None if x is None else np.asarray(x)

        estimate = {k: (np.asarray(v) if isinstance(v, list) else v) for k, v in d.get("estimate", {}).items()}
        return cls(
            kind=d["kind"],
            verdict=d["verdict"],
            estimate=estimate,
            param_names=list(d.get("param_names", [])),
            covariance=arr(d.get("covariance")),
            residuals=arr(d.get("residuals")),
            residual_names=list(d.get("residual_names", [])),
            outliers=None if d.get("outliers") is None else np.asarray(d["outliers"], dtype=bool),
            reasons=list(d.get("reasons", [])),
            advice=list(d.get("advice", [])),
            metrics=dict(d.get("metrics", {})),
            method=d.get("method", ""),
            iterations=int(d.get("iterations", 0)),
        )
