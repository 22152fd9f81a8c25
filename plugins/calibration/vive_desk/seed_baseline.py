"""Seed 001's own calibration, verbatim, as the baseline of the benchmark and the tests.

Twelve parameters ``(rvec_desktop, tvec_desktop, rvec_tcp, tvec_tcp)``, residual per contact
``[p_measured - p_expected, rotvec(R_expected^T R_measured)]`` with fixed weights 1.0 (m) and
0.1 (rad -> m), summed squares minimised by ``scipy.optimize.minimize(method="L-BFGS-B",
ftol=1e-9, gtol=1e-9)`` with numerical gradients, started from the seed's step 1 for
T_base_desktop and the identity for T_tracker_tcp unless other starts are given. Per-contact
fixture orientations are used when the data have them (the seed uses the identity throughout).
No covariance, no noise model: that is what vgr's solver adds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_rotvec
from plugins.calibration.vive_desk.data import ViveDeskData
from plugins.calibration.vive_desk.initial import seed_step1_T_base_desktop

F64 = NDArray[np.float64]


@dataclass
class SeedResult:
    T_base_desktop: F64
    T_tracker_tcp: F64
    success: bool
    iterations: int
    cost: float


def _params(T: F64) -> F64:
    return np.concatenate([Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3]])


def seed_residuals(x: F64, data: ViveDeskData, weight_position: float, weight_rotation: float) -> F64:
    """Seed 001 step 2 weighted residual vector (6 per contact), vectorised over contacts."""
    R_BD = Rotation.from_rotvec(x[0:3]).as_matrix()
    R_KC = Rotation.from_rotvec(x[6:9]).as_matrix()
    R_exp = R_BD @ data.R_desktop_tcp  # T_BD @ [R_fix, q]
    p_exp = data.tcp_positions_desktop @ R_BD.T + x[3:6]
    R_BK = data.T_base_tracker[:, :3, :3]
    R_mea = R_BK @ R_KC  # T_BK @ T_KC
    p_mea = R_BK @ x[9:12] + data.T_base_tracker[:, :3, 3]
    rot = Rotation.from_matrix(np.transpose(R_exp, (0, 2, 1)) @ R_mea).as_rotvec()
    return np.hstack([(p_mea - p_exp) * weight_position, rot * weight_rotation]).ravel()


def seed_calibrate(
    data: ViveDeskData,
    *,
    T_base_desktop0: F64 | None = None,
    T_tracker_tcp0: F64 | None = None,
    weight_position: float = 1.0,
    weight_rotation: float = 0.1,
) -> SeedResult:
    """Seed 001's L-BFGS-B calibration (see module docstring)."""
    T_BD0 = seed_step1_T_base_desktop(data.T_base_tracker) if T_base_desktop0 is None else T_base_desktop0
    T_KC0 = np.eye(4) if T_tracker_tcp0 is None else T_tracker_tcp0
    x0 = np.concatenate([_params(T_BD0), _params(T_KC0)])

    def cost(x: F64) -> float:
        r = seed_residuals(x, data, weight_position, weight_rotation)
        return float(r @ r)

    res = minimize(cost, x0, method="L-BFGS-B", options={"ftol": 1e-9, "gtol": 1e-9})
    return SeedResult(
        T_from_rotvec(res.x[0:3], res.x[3:6]),
        T_from_rotvec(res.x[6:9], res.x[9:12]),
        bool(res.success),
        int(res.nit),
        float(res.fun),
    )
