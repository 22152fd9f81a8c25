"""Depth captures of a known flat target, and the per-pixel arrays the depth gap fits.

A **capture** (:class:`DepthFrame`) is one depth image ``(H, W)`` of z along the optical axis in
metres (NaN or <= 0 where invalid: the ``32FC1`` convention of vgr's depth images), with the pose
``T_cam_target`` of the target in the camera frame when it is known (from a board detection, or the
simulation's truth). The target is a plane: the ``z = 0`` plane of its frame (a calibration board's
plane), optionally limited to ``target_extent_m = (x_min, x_max, y_min, y_max)`` in that frame
(pixels whose ray meets the plane outside it are not used). :class:`DepthCaptures` adds the camera
(``K``, distortion ``D`` of the depth image, usually none) and the sensor's stated noise law
``sigma(z) = const + quad * z^2`` when the integrator knows it.

:func:`prepare` turns them into :class:`Pixels`: every valid pixel's capture, normalised image
coordinates ``x, y`` (the ray ``(x, y, 1)``), measured range along the ray ``r_meas = z |(x, y, 1)|``
and the range predicted from the target ``r_ref = c / (n . d)`` for the plane ``n . p = c``. With
``target = "known"`` the plane is the pose's; with ``target = "fit"`` (no pose) each capture's plane
is fitted robustly (``scipy.optimize.least_squares``, soft-L1 loss) and stays free in every model:
its three parameters (two tilts, the distance) enter as linear columns (the range's derivatives at
the fitted plane) of that capture alone. Such a fit absorbs whatever a plane can, so only effects it
cannot absorb are identifiable (:func:`identifiable_share`). Every refusal is a
:class:`DepthGapInputError` (a ValueError: exit code 2) that says which capture and what to do.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

__all__ = [
    "MIN_PIXELS",
    "DepthCaptures",
    "DepthFrame",
    "DepthGapInputError",
    "Pixels",
    "SigmaLaw",
    "identifiable_share",
    "prepare",
]

MIN_PIXELS = 50  # a capture with fewer valid pixels on the target is left out
OPENCV_DISTORTION_LENGTHS = (4, 5, 8, 12, 14)  # what cv2.undistortPoints takes


class DepthGapInputError(ValueError):
    """Input the depth gap cannot use; the message says which and what to do."""


@dataclass(frozen=True)
class SigmaLaw:
    """The sensor's stated range noise, 1 sigma: ``const_m + quad_per_m * z^2`` (m)."""

    const_m: float
    quad_per_m: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.const_m) and np.isfinite(self.quad_per_m)) or self.const_m < 0 or self.quad_per_m < 0:
            raise DepthGapInputError(f"the stated noise law needs finite, non-negative terms, got {self}")
        if self.const_m == 0 and self.quad_per_m == 0:
            raise DepthGapInputError("the stated noise law is zero: give sigma_const_m > 0 or sigma_quad_per_m > 0")

    def __call__(self, z: F64) -> F64:
        return self.const_m + self.quad_per_m * np.asarray(z, float) ** 2


@dataclass(frozen=True, eq=False)
class DepthFrame:
    """One depth capture (module docstring)."""

    name: str
    depth: F64
    T_cam_target: F64 | None = None
    target_extent_m: tuple[float, float, float, float] | None = None


@dataclass(eq=False)
class DepthCaptures:
    """Captures of one depth camera: ``K`` (3x3), image size ``(width, height)``, distortion ``D``."""

    frames: list[DepthFrame]
    K: F64
    size: tuple[int, int]
    D: F64 | None = None
    sigma: SigmaLaw | None = None
    source: str = ""
    rejected: list[tuple[str, str]] = field(default_factory=list)


@dataclass(frozen=True, eq=False)
class Pixels:
    """The valid pixels of all captures, flattened (module docstring); ``jac`` (n, 3): the plane's
    columns of each pixel (``target = "fit"``), None with known poses."""

    names: tuple[str, ...]
    capture: NDArray[np.int64]
    u: F64
    v: F64
    x: F64
    y: F64
    r_meas: F64
    r_ref: F64
    z_ref: F64
    planes: F64  # (n_captures, 4): n (unit, camera frame) and c of n . p = c
    jac: F64 | None
    target: str  # "known" | "fit"
    size: tuple[int, int]

    @property
    def n_captures(self) -> int:
        return len(self.names)

    @property
    def residual(self) -> F64:
        """Measured minus predicted range (m): what the effects and the noise make."""
        return self.r_meas - self.r_ref

    def take(self, keep: NDArray[np.bool_]) -> Pixels:
        """The pixels where *keep* is True (the captures and their numbering unchanged)."""
        return Pixels(
            self.names, self.capture[keep], self.u[keep], self.v[keep], self.x[keep], self.y[keep],
            self.r_meas[keep], self.r_ref[keep], self.z_ref[keep], self.planes,
            None if self.jac is None else self.jac[keep], self.target, self.size,
        )  # fmt: skip

    def of(self, captures: NDArray[np.int64]) -> NDArray[np.bool_]:
        """The mask of the pixels of the given captures."""
        return np.isin(self.capture, captures)


def _rays(K: F64, D: F64 | None, size: tuple[int, int]) -> tuple[F64, F64, F64, F64]:
    """Per pixel of the image (row-major): u, v and the normalised coordinates x, y of its ray."""
    w, h = size
    u, v = (a.ravel().astype(float) for a in np.meshgrid(np.arange(w), np.arange(h)))
    if D is not None and np.any(np.asarray(D) != 0):
        import cv2

        xy = cv2.undistortPoints(np.column_stack((u, v)).reshape(-1, 1, 2), K, np.asarray(D, float)).reshape(-1, 2)
        return u, v, xy[:, 0].astype(float), xy[:, 1].astype(float)
    return u, v, (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]


def _known_plane(T: F64) -> tuple[F64, float]:
    n = np.asarray(T, float)[:3, 2].copy()
    c = float(n @ np.asarray(T, float)[:3, 3])
    return (n, c) if c > 0 else (-n, -c)


def _in_extent(T: F64, pts: F64, extent: tuple[float, float, float, float] | None) -> NDArray[np.bool_]:
    if extent is None:
        return np.ones(len(pts), dtype=bool)
    R, t = T[:3, :3], T[:3, 3]
    q = (pts - t) @ R  # in the target frame
    x0, x1, y0, y1 = extent
    return (q[:, 0] >= x0) & (q[:, 0] <= x1) & (q[:, 1] >= y0) & (q[:, 1] <= y1)


def _fit_plane(d: F64, r_meas: F64) -> tuple[F64, float]:
    """A robust plane ``n . p = c`` through the points ``r_meas d`` (soft-L1 loss on the range)."""
    from scipy.optimize import least_squares

    p = d * r_meas[:, None]
    centre = np.median(p, axis=0)
    _, _, vt = np.linalg.svd(p - centre, full_matrices=False)
    n0 = vt[2] if vt[2] @ centre > 0 else -vt[2]
    t1 = np.cross(n0, [1.0, 0.0, 0.0] if abs(n0[0]) < 0.9 else [0.0, 1.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n0, t1)
    c0 = float(n0 @ centre)

    def plane(q: F64) -> tuple[F64, float]:
        n = n0 + q[0] * t1 + q[1] * t2
        return n / np.linalg.norm(n), c0 + q[2]

    def res(q: F64) -> F64:
        n, c = plane(q)
        return r_meas - c / np.clip(d @ n, 1e-6, None)

    r0 = res(np.zeros(3))
    scale = max(1.4826 * float(np.median(np.abs(r0 - np.median(r0)))), 1e-5)
    sol = least_squares(res, np.zeros(3), loss="soft_l1", f_scale=2.0 * scale, x_scale=[1e-3, 1e-3, 1e-3])
    return plane(sol.x)


def _plane_columns(d: F64, n: F64, c: float) -> F64:
    """Derivatives of the predicted range ``c / (n . d)`` by two tilts of n and by c (n, 3)."""
    t1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    nd = d @ n
    return np.column_stack((-c * (d @ t1) / nd**2, -c * (d @ t2) / nd**2, 1.0 / nd))


def _target_mode(captures: DepthCaptures, target: str) -> str:
    posed = [f.T_cam_target is not None for f in captures.frames]
    if target == "auto":
        if all(posed):
            return "known"
        if not any(posed):
            return "fit"
        missing = [f.name for f in captures.frames if f.T_cam_target is None]
        raise DepthGapInputError(
            f"the target pose is missing for {len(missing)} of {len(posed)} captures ({', '.join(missing[:3])}): "
            "give it for every capture, or none (the plane is then fitted per capture: --target fit)"
        )
    if target == "known" and not all(posed):
        first = next(f.name for f in captures.frames if f.T_cam_target is None)
        raise DepthGapInputError(
            f"capture {first!r}: the target pose is missing (target 'known' needs one per capture)"
        )
    if target not in ("known", "fit"):
        raise DepthGapInputError(f"target must be 'auto', 'known' or 'fit', got {target!r}")
    return target


def _check_frame(frame: DepthFrame, size: tuple[int, int]) -> None:
    depth = np.asarray(frame.depth)
    if depth.ndim != 2 or depth.shape != (size[1], size[0]):
        raise DepthGapInputError(
            f"capture {frame.name!r}: depth image of shape {depth.shape}, the camera is {size[0]} x {size[1]} "
            f"(need ({size[1]}, {size[0]}))"
        )
    if frame.T_cam_target is not None:
        T = np.asarray(frame.T_cam_target, float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise DepthGapInputError(f"capture {frame.name!r}: T_cam_target must be a finite 4x4 pose")
        if abs(np.linalg.det(T[:3, :3]) - 1.0) > 1e-6:
            raise DepthGapInputError(f"capture {frame.name!r}: T_cam_target's rotation is not a rotation")


def _check_camera(captures: DepthCaptures) -> None:
    K = np.asarray(captures.K, float)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise DepthGapInputError(f"the camera matrix K must be a finite 3x3 with fx, fy > 0, got {K.tolist()}")
    w, h = captures.size
    if w < 4 or h < 4:
        raise DepthGapInputError(f"image size {w} x {h}: too small for a depth image")
    if captures.D is not None:
        D = np.asarray(captures.D, float).ravel()
        if len(D) not in OPENCV_DISTORTION_LENGTHS or not np.all(np.isfinite(D)):
            raise DepthGapInputError(
                f"the distortion D must be 4, 5, 8, 12 or 14 finite coefficients (OpenCV's order), got {D.tolist()}"
            )
    if not captures.frames:
        raise DepthGapInputError("no depth captures: give depth images of a flat target (docs/depth_gap.md)")


def prepare(captures: DepthCaptures, target: str = "auto") -> Pixels:
    """The :class:`Pixels` of *captures* (module docstring); captures with fewer than
    :data:`MIN_PIXELS` valid pixels are left out and listed in ``captures.rejected``."""
    _check_camera(captures)
    mode = _target_mode(captures, target)
    K = np.asarray(captures.K, float)
    u, v, x, y = _rays(K, captures.D, captures.size)
    norm = np.sqrt(1.0 + x * x + y * y)
    d = np.column_stack((x, y, np.ones_like(x))) / norm[:, None]
    parts: list[tuple[NDArray[Any], ...]] = []
    names: list[str] = []
    planes: list[list[float]] = []
    for frame in captures.frames:
        _check_frame(frame, captures.size)
        z = np.asarray(frame.depth, float).ravel()
        ok = np.isfinite(z) & (z > 0)
        r_meas = z * norm
        if mode == "known":
            T = np.asarray(frame.T_cam_target, float)
            n, c = _known_plane(T)
            nd = d @ n
            ok &= nd > 1e-3
            r_ref = np.where(ok, c / np.where(ok, nd, 1.0), np.nan)
            ok &= _in_extent(T, d * np.nan_to_num(r_ref)[:, None], frame.target_extent_m)
        elif np.count_nonzero(ok) >= MIN_PIXELS:
            n, c = _fit_plane(d[ok], r_meas[ok])
            r_ref = c / np.clip(d @ n, 1e-6, None)
        if np.count_nonzero(ok) < MIN_PIXELS:
            why = "no valid pixel" if not np.any(ok) else f"{int(np.count_nonzero(ok))} valid pixels"
            captures.rejected.append((frame.name, f"{why} on the target (need {MIN_PIXELS})"))
            continue
        idx = np.flatnonzero(ok)
        cols = _plane_columns(d[idx], n, c) if mode == "fit" else np.zeros((len(idx), 0))
        k = np.full(len(idx), len(names), dtype=np.int64)
        parts.append((k, u[idx], v[idx], x[idx], y[idx], r_meas[idx], r_ref[idx], r_ref[idx] / norm[idx], cols))
        names.append(frame.name)
        planes.append([*n, c])
    if not parts:
        raise DepthGapInputError(
            f"none of the {len(captures.frames)} captures has {MIN_PIXELS} valid pixels on the target "
            f"({'; '.join(f'{a}: {b}' for a, b in captures.rejected[:3])})"
        )
    k, u_, v_, x_, y_, r_meas_, r_ref_, z_ref_, jac = (np.concatenate([p[i] for p in parts]) for i in range(9))
    return Pixels(
        tuple(names), k.astype(np.int64), u_, v_, x_, y_, r_meas_, r_ref_, z_ref_, np.asarray(planes, float),
        jac if mode == "fit" else None, mode, captures.size,
    )  # fmt: skip


def identifiable_share(px: Pixels, columns: F64) -> F64:
    """Per column, the share of its energy a per-capture plane fit cannot absorb (1 with known poses):
    ``|P c|^2 / |c|^2`` with ``P`` projecting out each capture's plane columns."""
    if px.jac is None:
        return np.ones(columns.shape[1])
    left = project_out(px, columns)
    total = np.sum(columns**2, axis=0)
    return np.where(total > 0, np.sum(left**2, axis=0) / np.where(total > 0, total, 1.0), 0.0)


def project_out(px: Pixels, a: F64, weights: F64 | None = None) -> F64:
    """*a* (n,) or (n, k) with each capture's plane columns fitted out (weighted by *weights*)."""
    if px.jac is None:
        return a
    out = np.array(a, dtype=float, copy=True)
    w = np.ones(len(px.capture)) if weights is None else weights
    for k in np.unique(px.capture):
        m = px.capture == k
        J = px.jac[m] * w[m, None]
        rhs = out[m] * (w[m, None] if out.ndim == 2 else w[m])
        coef, *_ = np.linalg.lstsq(J, rhs, rcond=None)
        out[m] = (rhs - J @ coef) / (w[m, None] if out.ndim == 2 else w[m])
    return out


def split_names(px: Pixels, captures: Sequence[int]) -> list[str]:
    """The names of the given capture indices."""
    return [px.names[i] for i in captures]
