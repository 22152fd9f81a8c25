"""The depth catalog of the depth model-gap workflow: which range errors of a depth camera can be
named, and the feature columns (functions of the range and the pixel) each one adds to the model.

The model of a measured range is ``r_meas = r_true + sum_k theta_k phi_k(r, x, y) + noise``, with
``r`` the range *along the pixel's ray* (metres) to the known target and ``x = (u - cx) / fx``,
``y = (v - cy) / fy`` the pixel's normalised image coordinates (the tangents of the ray's angles).
The baseline is the camera as specified: no free coefficient (with the target's pose known) or only
each capture's plane (``target = "fit"``, :mod:`.data`). Every effect is linear in its coefficients,
so a model is the set of its effects' columns.

======================  =========================  ==========================================================
effect                  columns                    what it is physically
======================  =========================  ==========================================================
``range_scale``         ``r``                      a range scale error (a baseline or focal length off in a
                                                   triangulating camera; a modulation-clock error in a ToF)
``range_bias``          ``1``                      a constant offset along every ray (a ToF's phase / time
                                                   offset; a stereo camera's disparity offset at one range)
``range_quadratic``     ``r^2``                    an error growing with the square of the range (a stereo /
                                                   structured-light disparity bias: dz = z^2 d_bias / (f B))
``radial_pattern``      ``rho^2, rho^4``           a per-pixel bias rising towards the image's edges,
                                                   rho^2 = x^2 + y^2 (lens / illumination fall-off, a ToF's
                                                   per-pixel timing, an IR projector's pattern)
``polynomial_pattern``  ``x, y, x^2, xy, y^2``     a per-pixel bias smooth over the image but not radial
                                                   (a stereo pair's residual rectification error, a tilt
                                                   of the projector)
``wiggling``            ``sin, cos(2 pi r / L)``   a ToF's periodic range error ("wiggling": the modulation
                                                   is not a pure sinusoid), period ``L`` the sensor's
======================  =========================  ==========================================================

``r`` in the columns is the range predicted from the target (known pose) or from the baseline's
plane fit, not the measured one: a noisy regressor would correlate with the noise it explains.
With the plane fitted per capture, a column the plane absorbs cannot be tested: ``range_scale``
entirely (a plane scaled about the camera is a plane), the others in part (:mod:`.data` measures the
share left); the workflow leaves an untestable effect out and says so.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

__all__ = [
    "CATALOG",
    "DEFAULT_WIGGLE_PERIOD_M",
    "DepthEffect",
    "effect_by_name",
    "effect_columns",
    "feature_matrix",
    "report_values",
]

#: the wiggling period of a ToF camera at 200 MHz modulation (c / (2 f) / 4: the 4th harmonic's)
DEFAULT_WIGGLE_PERIOD_M = 0.1874


@dataclass(frozen=True)
class DepthEffect:
    """One catalog effect: its name, the names of its coefficients (one per column), what it is."""

    name: str
    coefficients: tuple[str, ...]
    description: str
    unit: str  # of the coefficients in the report ("mm", "mm/m", "ppm")

    @property
    def n_params(self) -> int:
        """The coefficients it frees (the parsimony rule of the camera selection counts them)."""
        return len(self.coefficients)


CATALOG: tuple[DepthEffect, ...] = (
    DepthEffect("range_scale", ("scale_ppm",), "a range scale error: r_meas = (1 + s) r", "ppm"),
    DepthEffect("range_bias", ("bias_mm",), "a constant range offset along every ray", "mm"),
    DepthEffect("range_quadratic", ("quad_mm_per_m2",), "a range error growing as r^2 (disparity bias)", "mm/m^2"),
    DepthEffect("radial_pattern", ("rho2_mm", "rho4_mm"), "a per-pixel bias rising towards the image edges", "mm"),
    DepthEffect(
        "polynomial_pattern",
        ("x_mm", "y_mm", "x2_mm", "xy_mm", "y2_mm"),
        "a smooth per-pixel bias over the image, not radial (a 2-D quadratic in x, y)",
        "mm",
    ),
    DepthEffect("wiggling", ("sin_mm", "cos_mm"), "a ToF's periodic range error (sin, cos of 2 pi r / L)", "mm"),
)

#: how a fitted coefficient (SI: the column's multiplier in metres of range) becomes its report unit
_REPORT_SCALE = {"ppm": 1e6, "mm": 1e3, "mm/m^2": 1e3}


def effect_by_name(name: str) -> DepthEffect:
    """The catalog effect called *name*; ValueError naming the catalog otherwise."""
    for e in CATALOG:
        if e.name == name:
            return e
    raise ValueError(f"unknown depth effect {name!r}: the catalog has {', '.join(e.name for e in CATALOG)}")


def effect_columns(effect: DepthEffect, r: F64, x: F64, y: F64, wiggle_period_m: float) -> F64:
    """The columns (n, k) of *effect* at ranges *r* (m) and normalised pixel coordinates *x*, *y*."""
    name = effect.name
    if name == "range_scale":
        return r[:, None]
    if name == "range_bias":
        return np.ones((len(r), 1))
    if name == "range_quadratic":
        return (r * r)[:, None]
    if name == "radial_pattern":
        rho2 = x * x + y * y
        return np.column_stack((rho2, rho2 * rho2))
    if name == "polynomial_pattern":
        return np.column_stack((x, y, x * x, x * y, y * y))
    if name == "wiggling":
        phase = 2.0 * np.pi * r / wiggle_period_m
        return np.column_stack((np.sin(phase), np.cos(phase)))
    raise ValueError(f"no columns for depth effect {name!r}")


def feature_matrix(effects: Iterable[DepthEffect], r: F64, x: F64, y: F64, wiggle_period_m: float) -> F64:
    """The columns of every effect in *effects*, side by side ((n, 0) for none)."""
    cols = [effect_columns(e, r, x, y, wiggle_period_m) for e in effects]
    return np.column_stack(cols) if cols else np.zeros((len(r), 0))


def report_values(effect: DepthEffect, theta: Iterable[float]) -> dict[str, float]:
    """The fitted coefficients of *effect* in its report unit, by coefficient name."""
    k = _REPORT_SCALE[effect.unit]
    return {name: float(k * t) for name, t in zip(effect.coefficients, theta, strict=True)}
