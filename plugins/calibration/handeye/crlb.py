"""Cramér–Rao bound of hand-eye calibration at the true poses, for a given noise model.

The Fisher information of the errors-in-variables model (``ml_model``) at the truth is ``J^T J``
of the whitened residual Jacobian (residuals are zero there); the bound for (X, Y) is the inverse
of its Schur complement after eliminating the true robot poses. No unbiased estimator can have a
smaller covariance; the ML estimate reaches it as the noise gets small. The parametrisation is the
same as the solver's covariance (decoupled perturbations, translation first), so
``sqrt(trace)`` of the 3x3 blocks is the RMS translation (m) and rotation-angle (rad) bound.
With per-sample camera covariances (``NoiseModel.camera_covariances``, or ``camera_covariances=``
here) each sample's camera rows are whitened by its own inverse Cholesky factor, as in the ML.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from plugins.calibration.handeye.ml_model import EivModel
from plugins.calibration.handeye.noise import NoiseModel
from plugins.calibration.handeye.problem import Setup, model_camera_poses

F64 = NDArray[np.float64]

__all__ = ["crlb_covariance", "rms_bounds"]


def crlb_covariance(
    setup: Setup, T_base_tcp: F64, X: F64, Y: F64, noise: NoiseModel, *, camera_covariances: ArrayLike | None = None
) -> F64:
    """12 x 12 Cramér–Rao bound of (X, Y) at the true robot poses ``T_base_tcp`` and unknowns X, Y;
    ``camera_covariances`` ``(n, 6, 6)``: each sample's camera noise (replacing ``noise``'s camera)."""
    M = np.asarray(T_base_tcp, dtype=float).reshape(-1, 4, 4)
    if camera_covariances is not None:
        noise = noise.with_camera_covariances(camera_covariances)
    B = model_camera_poses(setup, M, X, Y)
    model = EivModel(setup, M, B, noise, X, Y)
    st = model.state(np.zeros(model.n_params), jacobian=True)
    info = model.information_xy(st, np.ones(M.shape[0]))
    cov = np.linalg.inv(info)
    return 0.5 * (cov + cov.T)


def rms_bounds(cov: F64, block: int = 0) -> tuple[float, float]:
    """(RMS rotation angle in rad, RMS translation in m) of pose ``block`` (0 = X, 1 = Y)."""
    d = np.diag(cov)[6 * block : 6 * block + 6]
    return float(np.sqrt(d[3:].sum())), float(np.sqrt(d[:3].sum()))
