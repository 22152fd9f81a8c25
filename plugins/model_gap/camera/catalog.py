"""The camera catalog of the camera model-gap workflow: which lens and sensor effects can be named,
which of OpenCV's distortion coefficients each one frees, and the ``cv2.calibrateCamera`` flags of a
model made of a baseline and some effects.

Every model is OpenCV's own (``cv2.projectPoints`` / ``cv2.calibrateCamera``, the 14-coefficient
distortion vector ``k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4 tauX tauY``); nothing here projects a point.
A model is the *set of free coefficients*: the baseline (``k1, k2``: Brown's two radial terms, what a
plain lens needs) plus the coefficients of each effect added; every other coefficient is held at 0
with OpenCV's ``CALIB_FIX_*`` / ``CALIB_ZERO_TANGENT_DIST`` flags.

===============  ==================  ================================================================
effect           coefficients        what it is (OpenCV flag; reference)
===============  ==================  ================================================================
``radial_k3``    ``k3``              a third radial term r^6, wide-angle lenses (``CALIB_FIX_K3`` off)
``tangential``   ``p1 p2``           decentring of the lens elements (``CALIB_ZERO_TANGENT_DIST``
                                     off; Brown 1966)
``thin_prism``   ``s1 s2 s3 s4``     a lens element tilted to the axis (``CALIB_THIN_PRISM_MODEL``;
                                     Weng, Cohen & Herniou 1992)
``rational``     ``k4 k5 k6``        the radial denominator of the rational model
                                     (``CALIB_RATIONAL_MODEL``; Claus & Fitzgibbon 2005)
``tilted``       ``tauX tauY``       a sensor tilted to the optical axis, Scheimpflug
                                     (``CALIB_TILTED_MODEL``)
``board_shape``  every board point   a board not flat or not printed to scale: its points released
                                     (``cv2.calibrateCameraRO``; Strobl & Hirzinger 2011)
===============  ==================  ================================================================

``board_shape`` frees the board's points but the first and the end of the first row (they fix the
board's frame and scale) and the last one's height: 3 n - 7 numbers, so it needs every view to see
the whole board (the same points in every view: a chessboard or circle grid, not a partial ChArUco
view); for the parsimony rule it counts as more coefficients than any lens effect. Its
pseudo-coefficient in a model's free set is :data:`BOARD_POINTS`.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

__all__ = [
    "BASELINE",
    "BOARD_POINTS",
    "CATALOG",
    "COEFFICIENTS",
    "LENS_EFFECTS",
    "CameraEffect",
    "calibrate_flags",
    "effect_by_name",
    "free_coefficients",
]

#: OpenCV's distortion vector, in its order (the full 14-coefficient form)
COEFFICIENTS: tuple[str, ...] = (
    "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tauX", "tauY",
)  # fmt: skip

#: the pseudo-coefficient of a model whose board points are released (``cv2.calibrateCameraRO``)
BOARD_POINTS = "board_points"
BOARD_PARAMS = 10**6  # what board_shape counts as for parsimony: more than any lens effect

#: the coefficients every model fits (fx, fy, cx, cy are always free)
BASELINE: frozenset[str] = frozenset({"k1", "k2"})


@dataclass(frozen=True)
class CameraEffect:
    """One catalog effect: its name, the distortion coefficients it frees, what it is physically."""

    name: str
    coefficients: tuple[str, ...]
    description: str

    @property
    def releases_board(self) -> bool:
        return BOARD_POINTS in self.coefficients

    @property
    def n_params(self) -> int:
        """The coefficients it frees (``board_shape``: :data:`BOARD_PARAMS`, see the module docstring)."""
        return BOARD_PARAMS if self.releases_board else len(self.coefficients)


CATALOG: tuple[CameraEffect, ...] = (
    CameraEffect("radial_k3", ("k3",), "a third radial distortion term k3 r^6 (a wide-angle lens)"),
    CameraEffect("tangential", ("p1", "p2"), "tangential (decentring) distortion p1, p2: lens elements off the axis"),
    CameraEffect("thin_prism", ("s1", "s2", "s3", "s4"), "thin-prism distortion s1..s4: a lens element tilted"),
    CameraEffect("rational", ("k4", "k5", "k6"), "the rational radial model's denominator k4..k6 (strong distortion)"),
    CameraEffect("tilted", ("tauX", "tauY"), "a tilted sensor (Scheimpflug angles tauX, tauY)"),
    CameraEffect("board_shape", (BOARD_POINTS,), "the board is not flat or not printed to scale (its points released)"),
)


#: the catalog without ``board_shape``: the effects of the lens and the sensor alone (fast: no board
#: point is released)
LENS_EFFECTS: tuple[CameraEffect, ...] = tuple(e for e in CATALOG if not e.releases_board)


def effect_by_name(name: str) -> CameraEffect:
    """The catalog effect called *name*; ValueError naming the catalog otherwise."""
    for e in CATALOG:
        if e.name == name:
            return e
    raise ValueError(f"unknown camera effect {name!r}: the catalog has {', '.join(e.name for e in CATALOG)}")


def free_coefficients(effects: Iterable[CameraEffect]) -> frozenset[str]:
    """The coefficients the baseline plus *effects* fit."""
    free = set(BASELINE)
    for e in effects:
        free.update(e.coefficients)
    return frozenset(free)


def calibrate_flags(free: frozenset[str]) -> int:
    """The ``cv2.calibrateCamera`` flags that fit exactly the coefficients in *free* (the others stay
    at their given value, 0 unless an initial guess says otherwise)."""
    import cv2

    unknown = free - set(COEFFICIENTS) - {BOARD_POINTS}
    if unknown:
        raise ValueError(f"unknown distortion coefficients {sorted(unknown)}")
    flags = 0
    for name, fix in (("k1", cv2.CALIB_FIX_K1), ("k2", cv2.CALIB_FIX_K2), ("k3", cv2.CALIB_FIX_K3)):
        if name not in free:
            flags |= fix
    if not {"p1", "p2"} & free:
        flags |= cv2.CALIB_ZERO_TANGENT_DIST
    elif {"p1", "p2"} - free:
        raise ValueError("p1 and p2 are fitted together (OpenCV frees both or neither)")
    if {"k4", "k5", "k6"} & free:
        flags |= cv2.CALIB_RATIONAL_MODEL
        for name, fix in (("k4", cv2.CALIB_FIX_K4), ("k5", cv2.CALIB_FIX_K5), ("k6", cv2.CALIB_FIX_K6)):
            if name not in free:
                flags |= fix
    prism = {"s1", "s2", "s3", "s4"} & free
    if prism and prism != {"s1", "s2", "s3", "s4"}:
        raise ValueError("s1..s4 are fitted together (OpenCV frees all four or none)")
    if prism:
        flags |= cv2.CALIB_THIN_PRISM_MODEL
    tau = {"tauX", "tauY"} & free
    if tau and tau != {"tauX", "tauY"}:
        raise ValueError("tauX and tauY are fitted together (OpenCV frees both or neither)")
    if tau:
        flags |= cv2.CALIB_TILTED_MODEL
    return flags
