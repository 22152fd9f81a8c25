"""Input checks for hand-eye samples: shapes, NaN, rigid-transform validity, duplicates and units.

Bad input either raises :class:`HandEyeInputError` naming the samples at fault (by the caller's
sample ids when given, e.g. the ids of the file they came from, else by their 0-based position),
or is repaired in a documented, harmless way with a warning that ends up in the result's
``reasons``:

* NaN / infinity, wrong shapes, a last row other than ``[0 0 0 1]``, reflections (det < 0),
  rotations further than ``repair_tol`` from orthonormal: error.
* rotations off by less than ``repair_tol`` (float32 or rounded exports): re-orthonormalised,
  with a warning.
* exact duplicate samples (same robot and camera pose): later copies dropped, with a warning;
  a camera pose repeated while the robot moved (a stale detection): warning.
* units: translations whose typical size exceeds ``max_translation_m`` are millimetres, below
  ``min_translation_m`` (5 mm) metres read as millimetres (error).
  Mixed units (robot in m, camera in mm or the reverse) are caught by the scale test of
  ``consistency``, which needs a rotation estimate. The solver works in metres only; the loaders
  take ``length_unit="mm"``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.transforms import orthonormalize

F64 = NDArray[np.float64]

__all__ = ["HandEyeInputError", "ValidatedSamples", "validate_samples"]


class HandEyeInputError(ValueError):
    """The hand-eye input cannot be used as given; the message says which samples and why."""


@dataclass
class ValidatedSamples:
    """Checked (and possibly repaired) samples; ``index`` maps rows back to the caller's order."""

    T_base_tcp: F64
    T_cam_target: F64
    index: NDArray[np.int64]
    warnings: list[str] = field(default_factory=list)
    labels: list[str] = field(default_factory=list)  # the caller's id of each kept row
    n_given: int = 0  # samples before duplicates were dropped

    @property
    def n(self) -> int:
        return int(self.T_base_tcp.shape[0])


def _as_stack(poses: Sequence[ArrayLike] | ArrayLike, name: str) -> F64:
    try:
        A = np.asarray(poses, dtype=float)
    except (TypeError, ValueError) as exc:
        raise HandEyeInputError(f"{name}: cannot be read as an array of 4x4 poses ({exc})") from exc
    if A.ndim == 2 and A.shape == (4, 4):
        A = A[None]
    if A.ndim != 3 or A.shape[1:] != (4, 4):
        raise HandEyeInputError(f"{name} must be a sequence of 4x4 poses, got shape {A.shape}")
    return A


def _list(idx: NDArray[np.int64] | list[int], ids: list[str], limit: int = 8) -> str:
    """The samples at rows *idx*, named by their ids."""
    items = [ids[int(i)] for i in idx[:limit]]
    return ", ".join(items) + (f" ... ({len(idx)} in all)" if len(idx) > limit else "")


def _check_finite_and_rigid(
    A: F64, name: str, ids: list[str], exact_tol: float, repair_tol: float, warnings: list[str]
) -> F64:
    bad = np.flatnonzero(~np.all(np.isfinite(A), axis=(1, 2)))
    if bad.size:
        raise HandEyeInputError(f"{name}: NaN or infinity in sample(s) {_list(bad, ids)}")
    bad = np.flatnonzero(np.max(np.abs(A[:, 3] - (0.0, 0.0, 0.0, 1.0)), axis=1) > 1e-9)
    if bad.size:
        raise HandEyeInputError(f"{name}: last row is not [0, 0, 0, 1] in sample(s) {_list(bad, ids)}")
    R = A[:, :3, :3]
    det = np.linalg.det(R)
    bad = np.flatnonzero(det <= 0.0)
    if bad.size:
        raise HandEyeInputError(
            f"{name}: rotation has det <= 0 (a reflection, e.g. a left-handed frame) in sample(s) {_list(bad, ids)}"
        )
    dev = np.max(np.abs(np.transpose(R, (0, 2, 1)) @ R - np.eye(3)), axis=(1, 2))
    bad = np.flatnonzero(dev > repair_tol)
    if bad.size:
        raise HandEyeInputError(
            f"{name}: rotation is not orthonormal in sample(s) {_list(bad, ids)} "
            f"(max |R^T R - I| = {dev.max():.2e} > {repair_tol:.0e}); check the matrix layout "
            "(row/column major) and the rotation convention"
        )
    fix = np.flatnonzero(dev > exact_tol)
    if fix.size:
        A = A.copy()
        for i in fix:
            A[i, :3, :3] = orthonormalize(A[i, :3, :3])
        warnings.append(
            f"{name}: {fix.size} rotation(s) were {dev[fix].max():.1e} from orthonormal and were "
            f"re-orthonormalised (samples {_list(fix, ids)})"
        )
    return A


def _check_units(M: F64, B: F64 | None, max_translation_m: float, min_translation_m: float) -> None:
    """Plausible sizes of the translations (metres); *B* None: the camera's unit is not known."""
    for A, name in ((M, "robot poses T_base_tcp"), (B, "camera poses T_cam_target")):
        if A is None:
            continue
        size = float(np.median(np.linalg.norm(A[:, :3, 3], axis=1)))
        if size > max_translation_m:
            raise HandEyeInputError(
                f"{name}: median translation {size:.1f} m is not plausible; these look like millimetres. "
                "vgr works in metres: convert (or load with length_unit='mm')"
            )
        if size < min_translation_m:
            raise HandEyeInputError(
                f"{name}: median translation {size * 1e3:.3f} mm is not plausible (a TCP at the base "
                "origin, a target on the lens); metres read as millimetres? vgr works in metres"
            )


def _duplicates(M: F64, B: F64, ids: list[str], warnings: list[str]) -> NDArray[np.bool_]:
    n = M.shape[0]
    keep = np.ones(n, dtype=bool)
    flat_m, flat_b = M.reshape(n, -1), B.reshape(n, -1)
    dups: list[int] = []
    stale: list[tuple[int, int]] = []
    for j in range(1, n):
        same_m = np.max(np.abs(flat_m[:j] - flat_m[j]), axis=1) <= 1e-12
        same_b = np.max(np.abs(flat_b[:j] - flat_b[j]), axis=1) <= 1e-12
        if np.any(same_m & same_b):
            keep[j] = False
            dups.append(j)
        elif np.any(same_b & ~same_m):
            stale.append((int(np.flatnonzero(same_b & ~same_m)[0]), j))
    if dups:
        warnings.append(
            f"{len(dups)} exact duplicate sample(s) dropped (samples {_list(dups, ids)}): "
            "a copied sample would be counted twice"
        )
    if stale:
        pairs = ", ".join(f"{ids[j]} repeats {ids[i]}" for i, j in stale[:5])
        warnings.append(
            f"camera observation identical to an earlier one although the robot moved ({pairs}): "
            "stale or mis-associated detection?"
        )
    return keep


def validate_samples(
    T_base_tcp: Sequence[ArrayLike] | ArrayLike,
    T_cam_target: Sequence[ArrayLike] | ArrayLike,
    *,
    exact_tol: float = 1e-6,
    repair_tol: float = 1e-3,
    max_translation_m: float = 20.0,
    min_translation_m: float = 0.005,
    ids: Sequence[str] | None = None,
    camera_unit_known: bool = True,
) -> ValidatedSamples:
    """Check and normalise robot poses T_base_tcp and camera observations T_cam_target (metres).

    *ids* name the samples in messages (one per sample, e.g. the ids of the file they came from);
    default: their 0-based positions. *camera_unit_known* False: the camera's translations are in
    an unknown unit (``free_scale``), and their size is not checked.
    """
    M = _as_stack(T_base_tcp, "robot poses T_base_tcp")
    B = _as_stack(T_cam_target, "camera poses T_cam_target")
    if M.shape[0] != B.shape[0]:
        raise HandEyeInputError(f"{M.shape[0]} robot poses but {B.shape[0]} camera poses: every sample needs both")
    if M.shape[0] == 0:
        raise HandEyeInputError("no samples")
    names = [str(k) for k in range(M.shape[0])] if ids is None else [str(i) for i in ids]
    if len(names) != M.shape[0]:
        raise HandEyeInputError(f"{len(names)} sample ids for {M.shape[0]} samples")
    warnings: list[str] = []
    M = _check_finite_and_rigid(M, "robot poses T_base_tcp", names, exact_tol, repair_tol, warnings)
    B = _check_finite_and_rigid(B, "camera poses T_cam_target", names, exact_tol, repair_tol, warnings)
    _check_units(M, B if camera_unit_known else None, max_translation_m, min_translation_m)
    keep = _duplicates(M, B, names, warnings)
    index = np.flatnonzero(keep).astype(np.int64)
    return ValidatedSamples(M[keep], B[keep], index, warnings, [names[i] for i in index], M.shape[0])
