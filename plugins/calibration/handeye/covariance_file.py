"""Per-sample camera covariances in hand-eye pose files (``io``, ``stream_file``): reading, units, checks.

A sample (or a camera entry of a stream file) may carry its camera pose's covariance, the noise model
of :mod:`plugins.calibration.handeye.noise` (decoupled ``(dt, dphi)`` in the camera frame, ordered
``(tx, ty, tz, rx, ry, rz)``):

* ``camera_cov``: 36 numbers, the 6x6 matrix row-major (a nested 6x6 list is taken too), in the
  file's length unit squared for the translation block, rad^2 for the rotation block and
  length unit x rad for the cross terms;
* ``camera_sigma``: 6 numbers, the 1-sigma per axis (length unit, rad): a diagonal covariance.

One of the two per sample, and either every sample has one or none does (a file that gives some
and not others is refused, naming the samples without). The translation parts are converted to
metres with the poses (``mm``: the translation block times 1e-6, the cross terms 1e-3). In CSV the
columns are ``camera_cov_RC`` (R, C the row and column, 0-5) or ``camera_sigma_tx`` ...
``camera_sigma_rz``; in OpenCV YAML the keys ``camera_cov_<i>`` (a 6x6 ``!!opencv-matrix``) or
``camera_sigma_<i>`` (6x1 or 1x6) beside ``T1_<i>`` / ``T2_<i>``. A wrong count of numbers, a
non-finite, asymmetric or not positive-definite matrix is a ``HandEyeInputError`` naming the sample.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from plugins.calibration.handeye.noise import check_camera_covariances
from plugins.calibration.handeye.validation import HandEyeInputError

F64 = NDArray[np.float64]
AXES = ("tx", "ty", "tz", "rx", "ry", "rz")
CSV_COV_COLUMNS = tuple(f"camera_cov_{r}{c}" for r in range(6) for c in range(6))
CSV_SIGMA_COLUMNS = tuple(f"camera_sigma_{a}" for a in AXES)

__all__ = [
    "CSV_COV_COLUMNS",
    "CSV_SIGMA_COLUMNS",
    "covariance_entry",
    "covariance_from_csv",
    "covariances_in_metres",
    "csv_covariance_kind",
    "json_covariance",
]


def _numbers(value: Any, count: int, key: str, where: str) -> F64:
    try:
        a = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise HandEyeInputError(f"{where}: {key} is not a list of numbers ({exc})") from None
    if a.size != count:
        raise HandEyeInputError(f"{where}: {key} needs {count} numbers, got {a.size}")
    return a


def covariance_entry(cov: Any, sigma: Any, where: str) -> F64 | None:
    """The 6x6 covariance of a ``camera_cov`` (36 numbers, row-major) or ``camera_sigma`` (6) value,
    in the file's units; None when neither is given."""
    if cov is not None and sigma is not None:
        raise HandEyeInputError(f"{where}: give camera_cov or camera_sigma, not both")
    if cov is not None:
        return _numbers(cov, 36, "camera_cov (row-major 6x6)", where).reshape(6, 6)
    if sigma is not None:
        return np.diag(_numbers(sigma, 6, "camera_sigma (tx, ty, tz, rx, ry, rz)", where) ** 2)
    return None


def csv_covariance_kind(columns: set[str], path: object) -> str | None:
    """``"cov"``, ``"sigma"`` or None: which covariance columns a CSV header has (all of a kind, or none)."""
    kinds = []
    for kind, names in (("cov", CSV_COV_COLUMNS), ("sigma", CSV_SIGMA_COLUMNS)):
        have = [c for c in names if c in columns]
        if have and len(have) < len(names):
            missing = [c for c in names if c not in columns]
            raise HandEyeInputError(f"{path}: camera_{kind}_* columns incomplete, missing {missing[:6]}")
        if have:
            kinds.append(kind)
    if len(kinds) > 1:
        raise HandEyeInputError(f"{path}: give camera_cov_* or camera_sigma_* columns, not both")
    return kinds[0] if kinds else None


def covariance_from_csv(row: Mapping[str, str | None], kind: str | None, where: str) -> F64 | None:
    """A CSV row's covariance (``csv_covariance_kind``); None for no such columns or all cells empty."""
    if kind is None:
        return None
    names = CSV_COV_COLUMNS if kind == "cov" else CSV_SIGMA_COLUMNS
    cells = [(row.get(c) or "").strip() for c in names]
    if not any(cells):
        return None
    if not all(cells):
        raise HandEyeInputError(f"{where}: camera_{kind}_* cells partly empty (all or none)")
    try:
        values = [float(c) for c in cells]
    except ValueError as exc:
        raise HandEyeInputError(f"{where}: a camera_{kind}_* cell is not a number ({exc})") from None
    return covariance_entry(values if kind == "cov" else None, values if kind == "sigma" else None, where)


def covariances_in_metres(
    covs: Sequence[F64 | None], ids: Sequence[str], length_scale: float, source: object
) -> F64 | None:
    """The samples' covariances ``(n, 6, 6)`` in metres (translation parts times *length_scale*), checked
    (``noise.check_camera_covariances``), or None when no sample has one; some with and some without
    is an error naming those without."""
    if all(c is None for c in covs):
        return None
    without = [str(i) for i, c in zip(ids, covs, strict=True) if c is None]
    if without:
        shown = ", ".join(without[:8]) + (f" ... ({len(without)} in all)" if len(without) > 8 else "")
        raise HandEyeInputError(
            f"{source}: camera covariance given for some samples but not for {shown}: every sample or none"
        )
    s = np.array([length_scale] * 3 + [1.0] * 3)
    cov = np.stack([np.asarray(c, dtype=float) for c in covs]) * s[:, None] * s[None, :]
    try:
        return check_camera_covariances(cov, names=[str(i) for i in ids])
    except ValueError as exc:
        raise HandEyeInputError(f"{source}: {exc}") from None


def json_covariance(cov: F64) -> list[float]:
    """A 6x6 covariance as ``camera_cov``'s 36 numbers, row-major."""
    return [float(v) for v in np.asarray(cov, dtype=float).reshape(36)]
