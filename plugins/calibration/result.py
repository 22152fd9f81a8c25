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
from typing import Any, Literal, NamedTuple

import numpy as np
from scipy import stats
from scipy.spatial.transform import Rotation

from engine.plain_data import plain

Verdict = Literal["ok", "warning", "degenerate", "failed"]
USABLE_VERDICTS: frozenset[str] = frozenset({"ok", "warning"})

_MM, _DEG = 1e3, float(np.degrees(1.0))
_DIAGNOSTIC_PREFIXES = ("closed_form_", "initial_")  # estimate entries that document the start, not the result
RESULT_FORMAT = "vgr.calibration_result/1"
_JSON_FIELDS = ("kind", "verdict", "method", "iterations", "estimate", "param_names", "covariance", "residuals",
                "residual_names", "outliers", "reasons", "advice", "metrics")  # fmt: skip
_ANGLE_SUFFIXES = ("rx", "ry", "rz", "wx", "wy", "wz", "theta", "alpha", "beta")


class SummaryRow(NamedTuple):
    """One line of a result summary for people: ``value`` and ``sigma`` (1-sigma, None when the
    result has no covariance for it) in ``unit`` (``mm`` or ``deg``)."""

    name: str
    value: float
    sigma: float | None
    unit: str


def _is_transform(v: Any) -> bool:
    if isinstance(v, str | bytes | dict) or v is None:
        return False
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        return False
    return a.shape == (4, 4)


def _is_point(v: Any) -> bool:
    if isinstance(v, str | bytes | dict) or v is None:
        return False
    try:
        return np.asarray(v, dtype=float).shape == (3,)
    except (TypeError, ValueError):
        return False


def _numbers(x: list[Any]) -> np.ndarray:
    """A JSON list as an array, ``null`` among numbers (written for NaN) NaN again."""
    a = np.asarray(x)
    if a.dtype == object:
        try:
            return np.asarray(x, dtype=float)
        except (TypeError, ValueError):  # documents, not numbers
            return a
    return a


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

    def confidence_threshold(
        self, k: int, level: float = 0.95, dof: float | None = None, f_scale: float | None = None
    ) -> float:
        """Bound of ``d^T C^-1 d`` for the ``level`` confidence region of ``k`` parameters.

        ``C`` is the ``k x k`` block of :attr:`covariance` belonging to those parameters and ``d``
        the estimate's deviation from the truth (in the solver's perturbation). When the covariance
        is known (declared noise, no a-posteriori scaling), ``d^T C^-1 d`` is chi-square with ``k``
        degrees of freedom. When it rests on a variance estimated from the residuals, it is itself
        uncertain and ``f_scale * d^T C^-1 d / k`` follows Fisher's ``F(k, dof)`` (exactly, with
        ``f_scale = 1``, for one variance factor; Kenward-Roger's ``dof`` and ``f_scale`` for
        several variance components), a wider region. ``dof`` and ``f_scale`` default to
        ``metrics["covariance_dof"]`` and ``metrics["covariance_f_scale"]`` (absent: known
        covariance, resp. 1). Solvers document which block those refer to.
        """
        if dof is None:
            dof = self.metrics.get("covariance_dof")
        if dof is None or not np.isfinite(dof):
            return float(stats.chi2.ppf(level, k))
        if f_scale is None:
            f_scale = self.metrics.get("covariance_f_scale", 1.0)
        return float(k * stats.f.ppf(level, k, dof) / f_scale)

    def summary_rows(self) -> list[SummaryRow]:
        """The estimate for people: rows of name, value, 1-sigma and unit, in mm and degrees.

        * every 4x4 transform ``T_a_b`` of the estimate gives six rows: ``T_a_b.x/y/z`` (translation,
          mm) and ``T_a_b.rotvec_x/y/z`` (rotation vector, deg). The 1-sigma comes from the
          covariance parameters ``T_a_b.tx|vx`` ... and ``T_a_b.rx|wx`` ...: for the rotation it is
          the standard deviation of a small rotation about that axis of frame *a* (the solvers'
          perturbation), which is what a user compares with a tolerance;
        * every 3-vector with covariance parameters ``name.x/y/z`` (e.g. ``p_flange_tcp``) gives
          three rows in mm;
        * every remaining covariance parameter gives one row: its value from the estimate (a scalar
          of that name, or its entry in ``estimate["offsets"]``, shown as ``name (change)``), in deg
          when the name ends in an angle (``rx``, ``wz``, ``theta``, ``alpha``, ``beta``), in px when
          it ends in ``_px`` (camera intrinsics), unitless (``1``) when it starts with ``distortion.``,
          else mm.

        Entries named ``closed_form_*`` / ``initial_*`` (the solver's starting point) are left out.
        """
        std = self.std()
        used: set[str] = set()

        def sigma(key: str, axis: str, kinds: tuple[str, str], scale: float) -> float | None:
            for k in kinds:
                name = f"{key}.{k}{axis}"
                if name in std:
                    used.add(name)
                    return std[name] * scale
            return None

        rows: list[SummaryRow] = []
        for key, value in self.estimate.items():
            if key.startswith(_DIAGNOSTIC_PREFIXES):
                continue
            if _is_transform(value):
                T = np.asarray(value, dtype=float)
                rv = Rotation.from_matrix(T[:3, :3]).as_rotvec()
                for i, a in enumerate("xyz"):
                    rows.append(SummaryRow(f"{key}.{a}", float(T[i, 3] * _MM), sigma(key, a, ("t", "v"), _MM), "mm"))
                for i, a in enumerate("xyz"):
                    s = sigma(key, a, ("r", "w"), _DEG)
                    rows.append(SummaryRow(f"{key}.rotvec_{a}", float(rv[i] * _DEG), s, "deg"))
            elif _is_point(value) and any(f"{key}.{a}" in std for a in "xyz"):
                v = np.asarray(value, dtype=float)
                for i, a in enumerate("xyz"):
                    s = std.get(f"{key}.{a}")
                    used.add(f"{key}.{a}")
                    rows.append(SummaryRow(f"{key}.{a}", float(v[i] * _MM), None if s is None else s * _MM, "mm"))
        offsets = self.estimate.get("offsets")
        offsets = offsets if isinstance(offsets, dict) else {}
        for name in self.param_names:
            if name in used:
                continue
            if name.endswith("_px"):  # image quantities (camera intrinsics)
                scale, unit = 1.0, "px"
            elif name.startswith("distortion."):  # lens distortion coefficients have no unit
                scale, unit = 1.0, "1"
            elif name.rsplit(".", 1)[-1] in _ANGLE_SUFFIXES:
                scale, unit = _DEG, "deg"
            else:
                scale, unit = _MM, "mm"
            if name in offsets:
                label, value = f"{name} (change)", offsets[name]
            elif np.isscalar(self.estimate.get(name)) and not isinstance(self.estimate.get(name), str):
                label, value = name, self.estimate[name]
            else:
                continue
            s = std.get(name)
            rows.append(SummaryRow(label, float(value) * scale, None if s is None else s * scale, unit))
        return rows

    def reason_lines(self) -> list[str]:
        """The end of a text report: ``reasons:`` and ``advice:``, each with its ``  - item`` lines
        (a heading only when it has items)."""
        lines: list[str] = []
        for title, items in (("reasons", self.reasons), ("advice", self.advice)):
            if items:
                lines += [f"{title}:"] + [f"  - {x}" for x in items]
        return lines

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (numpy arrays become nested lists), format ``vgr.calibration_result/1``
        (its JSON Schema: plugins/calibration/schemas/result.schema.json). A value that is not a
        number (NaN: not measured, e.g. no held-out figure with ``--no-holdout``; an infinite one) is
        ``null``: strict JSON parsers refuse a bare ``NaN``."""
        fields = {name: getattr(self, name) for name in _JSON_FIELDS}
        return {"format": RESULT_FORMAT, **plain(fields, nan_as_none=True)}

    def to_json(self, **kwargs: Any) -> str:
        return json.dumps(self.to_dict(), **{**kwargs, "allow_nan": False})

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CalibrationResult:
        """Inverse of :meth:`to_dict` (lists that were arrays become arrays again)."""

        def arr(x: Any) -> np.ndarray | None:
            return None if x is None else _numbers(x)

        estimate = {k: (_numbers(v) if isinstance(v, list) else v) for k, v in d.get("estimate", {}).items()}
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
            metrics={k: (float("nan") if v is None else v) for k, v in d.get("metrics", {}).items()},
            method=d.get("method", ""),
            iterations=int(d.get("iterations", 0)),
        )
