"""OpenCV fits of a camera model to board views, and the choice between the models.

:func:`fit_camera` runs ``cv2.calibrateCamera`` (standard and rational models) or
``cv2.fisheye.calibrate`` and keeps the intrinsics, each view's board pose and the sum of squared
reprojection distances, from which the fit's RMS and Bayesian information criterion follow.
:func:`choose_model` picks the model (for ``auto`` by BIC and a 5 % RMS gain, as
:mod:`.intrinsics` explains); :func:`intrinsics_covariance` is the covariance of the intrinsics with
the view poses eliminated (Schur complement), the corner noise estimated from the residuals.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from plugins.calibration.boards.detect import Detection
from plugins.camera.pinhole import DISTORTION, CameraModel

F64 = NDArray[np.float64]
ModelChoice = Literal["auto", "standard", "rational", "fisheye"]

__all__ = ["CameraFit", "ModelChoice", "ModelFit", "choose_model", "fit_camera", "intrinsics_covariance"]

MIN_RMS_GAIN = 0.05  # the rational model must lower the RMS by 5 % as well as win on BIC
_CRITERIA = (3, 200, 1e-12)  # cv2.TERM_CRITERIA_COUNT | EPS


@dataclass
class CameraFit:
    """One OpenCV fit of a camera model to board views: intrinsics, each view's board pose, the sum of
    squared reprojection distances, and the counts its RMS and BIC rest on."""

    model: str
    K: F64
    D: F64
    T: list[F64]
    rss: float  # sum of squared reprojection distances, px²
    n_points: int
    n_views: int

    @property
    def n_intrinsic(self) -> int:
        return 4 + DISTORTION[self.model][0]

    @property
    def rms(self) -> float:
        return float(np.sqrt(self.rss / self.n_points))

    @property
    def bic(self) -> float:
        m = 2 * self.n_points
        p = self.n_intrinsic + 6 * self.n_views
        return float(m * np.log(max(self.rss, 1e-300) / m) + p * np.log(m))


def _cv_lists(views: list[Detection]) -> tuple[list[NDArray[np.float32]], list[NDArray[np.float32]]]:
    obj = [np.asarray(v.object_points, np.float32).reshape(-1, 1, 3) for v in views]
    img = [np.asarray(v.image_points, np.float32).reshape(-1, 1, 2) for v in views]
    return obj, img


def _T(rvec: NDArray[Any], tvec: NDArray[Any]) -> F64:
    import cv2

    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, float).reshape(3, 1))[0]
    T[:3, 3] = np.asarray(tvec, float).ravel()
    return T


def _rss(camera: CameraModel, views: list[Detection], poses: list[F64]) -> float:
    return float(
        sum(
            np.sum((camera.project(T, v.object_points) - v.image_points) ** 2)
            for v, T in zip(views, poses, strict=True)
        )
    )


def fit_camera(model: str, views: list[Detection], size: tuple[int, int], guess: CameraFit | None = None) -> CameraFit:
    """OpenCV's fit of ``model`` to the views (``guess``: start from that fit's intrinsics)."""
    import cv2

    obj, img = _cv_lists(views)
    n_points = sum(v.n for v in views)
    if model == "fisheye":
        flags = cv2.fisheye.CALIB_RECOMPUTE_EXTRINSIC | cv2.fisheye.CALIB_FIX_SKEW
        obj64 = [o.astype(np.float64).reshape(1, -1, 3) for o in obj]
        img64 = [i.astype(np.float64).reshape(1, -1, 2) for i in img]
        _, K, D, rvecs, tvecs = cv2.fisheye.calibrate(obj64, img64, size, None, None, flags=flags, criteria=_CRITERIA)
    else:
        flags = cv2.CALIB_RATIONAL_MODEL if model == "rational" else 0
        K0, D0 = None, None
        if guess is not None:
            flags |= cv2.CALIB_USE_INTRINSIC_GUESS
            K0 = guess.K.copy()
            D0 = np.zeros(DISTORTION[model][0])
            D0[: min(5, guess.D.size)] = guess.D[:5]
        _, K, D, rvecs, tvecs = cv2.calibrateCamera(obj, img, size, K0, D0, flags=flags, criteria=_CRITERIA)
    K = np.asarray(K, float)
    D = np.asarray(D, float).ravel()[: DISTORTION[model][0]]
    poses = [_T(r, t) for r, t in zip(rvecs, tvecs, strict=True)]
    cam = CameraModel(size[0], size[1], K, D, model)  # type: ignore[arg-type]
    return CameraFit(model, K, D, poses, _rss(cam, views, poses), n_points, len(views))


def intrinsics_covariance(fit: CameraFit, views: list[Detection], size: tuple[int, int]) -> F64:
    """Covariance of (fx, fy, cx, cy, D...) with the view poses eliminated (module docstring)."""
    cam = CameraModel(size[0], size[1], fit.K, fit.D, fit.model)  # type: ignore[arg-type]
    nI = fit.n_intrinsic
    info = np.zeros((nI, nI))
    for v, T in zip(views, fit.T, strict=True):
        if fit.model == "fisheye":
            J = _fisheye_jacobian(cam, T, v.object_points)
            A, B = J[:, :8], J[:, 8:14]
        else:
            _, J = cam.project_with_jacobian(T, v.object_points)
            assert J is not None
            A, B = J[:, 6 : 6 + nI], J[:, :6]
        AtB = A.T @ B
        info += A.T @ A - AtB @ np.linalg.solve(B.T @ B, AtB.T)
    dof = 2 * fit.n_points - (nI + 6 * fit.n_views)
    sigma2 = fit.rss / max(dof, 1)  # per coordinate
    return sigma2 * np.linalg.pinv(info)


def _fisheye_jacobian(cam: CameraModel, T: F64, points: F64) -> F64:
    """``cv2.fisheye.projectPoints``' Jacobian: columns f (2), c (2), k (4), rvec (3), tvec (3)."""
    import cv2

    rvec, _ = cv2.Rodrigues(T[:3, :3])
    _, J = cv2.fisheye.projectPoints(
        points.reshape(-1, 1, 3), rvec, np.ascontiguousarray(T[:3, 3].reshape(3, 1)), cam.K, cam.D
    )
    return np.asarray(J, float)[:, :14]


class ModelFit(NamedTuple):
    """The model chosen: its fit, every candidate's RMS and BIC, and why it was chosen."""

    fit: CameraFit
    candidates: dict[str, dict[str, float]]
    why: str


def choose_model(model: ModelChoice, views: list[Detection], size: tuple[int, int]) -> ModelFit:
    """The model asked for, or for ``auto`` the standard or the rational one (module docstring)."""
    if model in ("standard", "fisheye"):
        f = fit_camera(model, views, size)
        return ModelFit(f, {model: {"rms_px": f.rms, "bic": f.bic}}, f"{model} model (as asked)")
    std = fit_camera("standard", views, size)
    rat = min((fit_camera("rational", views, size, std), fit_camera("rational", views, size)), key=lambda f: f.rss)
    cands = {f.model: {"rms_px": f.rms, "bic": f.bic} for f in (std, rat)}
    if model == "rational":
        return ModelFit(rat, cands, "rational model (as asked)")
    gain = 1.0 - rat.rms / std.rms
    if rat.bic < std.bic and gain >= MIN_RMS_GAIN:
        why = (
            f"rational model, chosen over standard by BIC (lower by {std.bic - rat.bic:.1f}) and RMS "
            f"({rat.rms:.4f} vs {std.rms:.4f} px)"
        )
        return ModelFit(rat, cands, why)
    if rat.bic < std.bic:
        why = (
            f"standard model: the rational one lowers the RMS by only {100 * gain:.1f} % ({rat.rms:.4f} vs "
            f"{std.rms:.4f} px; BIC alone would take it), so its 3 extra coefficients fit noise"
        )
    else:
        why = f"standard model, chosen over rational by BIC (RMS {std.rms:.4f} vs {rat.rms:.4f} px)"
    return ModelFit(std, cands, why)
