"""The Vive desk measurement model, its whitened residuals and exact analytic Jacobian.

Model (seed 001, one contact sample i):

    T_base_tracker_i = T_base_desktop @ T_desktop_tcp_i @ exp_rot(zeta_i) @ inv(T_tracker_tcp) (+ noise)

with ``T_desktop_tcp_i = [R_desktop_tcp_i, q_i]`` the fixture's nominal TCP pose and ``zeta_i`` the
unknown fixture scatter (a rotation about the TCP, prior N(0, sigma_fixture^2); for a sample with
free orientation zeta_i has no prior). The tracker noise is ``t_meas = t + n_p`` (base frame) and
``R_meas = R exp(n_r)`` (tracker frame). Residual blocks per sample, whitened:

    r_p = (t_meas - t_hat) / sigma_p          (3, base frame)
    r_r = log(R_hat^T R_meas) / sigma_r        (3, tracker frame)
    r_z = zeta_i / sigma_fixture               (3, only for samples with a fixture prior)

plus an optional prior on T_tracker_tcp. Unknowns ``x = (v_BD, w_BD, v_KC, w_KC, zeta...)`` perturb
reference poses the decoupled way (``t = t0 + v``, ``R = exp(w) R0``; BD = base->desktop in the base
frame, KC = tracker->tcp in the tracker frame). Jointly estimating the scatter is the exact ML
estimate with the scatter marginalised (linear-Gaussian), and keeps the Jacobian exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from engine.transforms import (
    T_from_Rt,
    exp_so3,
    hat,
    log_so3,
    so3_left_jacobian,
    so3_left_jacobian_inv,
    so3_right_jacobian,
)
from plugins.calibration.vive_desk.data import TrackerTcpPrior, ViveDeskData

F64 = NDArray[np.float64]

PARAM_NAMES = [
    f"{frame}.{c}" for frame in ("T_base_desktop", "T_tracker_tcp") for c in ("vx", "vy", "vz", "wx", "wy", "wz")
]
N_MAIN = 12
#: weight of the gauge rows that pin unidentifiable directions (1 um or 1 urad -> residual 100)
GAUGE_WEIGHT = 1e8


@dataclass
class DeskProblem:
    """Residuals/Jacobian of the Vive desk calibration around reference poses (x = 0)."""

    data: ViveDeskData
    T_BD0: F64
    T_KC0: F64
    R_fix_ref: F64  # (N, 3, 3) nominal fixture orientation (free samples: an initial guess)
    prior: TrackerTcpPrior | None = None
    gauge: F64 | None = None  # (k, 12) unit directions pinned at x = 0 (not identifiable by design)

    def __post_init__(self) -> None:
        nz = self.data.noise
        self.sigma_p = float(np.hypot(nz.tracker_position_sigma_m, nz.desk_point_sigma_m))
        self.sigma_r = float(nz.tracker_rotation_sigma_rad)
        self.sigma_fix = float(nz.fixture_rotation_sigma_rad)
        known = self.data.orientation_known
        # nuisance scatter for free samples always; for fixture samples only when sigma_fix > 0
        self.has_nuisance = ~known | (self.sigma_fix > 0)
        self.has_prior_rows = known & self.has_nuisance
        self.nuis_col = np.full(self.data.n, -1)
        self.nuis_col[self.has_nuisance] = N_MAIN + 3 * np.arange(int(self.has_nuisance.sum()))
        self.n_params = N_MAIN + 3 * int(self.has_nuisance.sum())
        self.q = self.data.tcp_positions_desktop
        self.t_meas = self.data.T_base_tracker[:, :3, 3]
        self.R_meas = self.data.T_base_tracker[:, :3, :3]

    # ------------------------------------------------------------------ poses

    def poses(self, x: F64) -> tuple[F64, F64]:
        """(T_base_desktop, T_tracker_tcp) at parameter vector *x*."""
        T_BD = T_from_Rt(exp_so3(x[3:6]) @ self.T_BD0[:3, :3], self.T_BD0[:3, 3] + x[0:3])
        T_KC = T_from_Rt(exp_so3(x[9:12]) @ self.T_KC0[:3, :3], self.T_KC0[:3, 3] + x[6:9])
        return T_BD, T_KC

    def zetas(self, x: F64) -> F64:
        """(N, 3) fixture scatter rotation vectors (zeros where the sample has no nuisance)."""
        z = np.zeros((self.data.n, 3))
        for i in np.flatnonzero(self.has_nuisance):
            c = self.nuis_col[i]
            z[i] = x[c : c + 3]
        return z

    def recentred(self, x: F64) -> tuple[DeskProblem, F64]:
        """Same problem with the reference poses moved to *x* (main part of x becomes 0)."""
        T_BD, T_KC = self.poses(x)
        x_new = x.copy()
        x_new[:N_MAIN] = 0.0
        return DeskProblem(self.data, T_BD, T_KC, self.R_fix_ref, self.prior, self.gauge), x_new

    # ------------------------------------------------------------------ residuals

    @property
    def n_residuals(self) -> int:
        return 6 * self.data.n + 3 * int(self.has_prior_rows.sum()) + self._n_tcp_prior_rows() + self.n_gauge

    @property
    def n_gauge(self) -> int:
        return 0 if self.gauge is None else int(self.gauge.shape[0])

    def residual_and_jacobian(self, x: F64, *, structural: bool = False) -> tuple[F64, F64]:
        """Whitened residual vector and its Jacobian at *x*.

        ``structural=True`` evaluates the design Jacobian of the noise-free model (predicted
        measurements, zero scatter): the residual returned is then zero.
        """
        R_BD = exp_so3(x[3:6]) @ self.T_BD0[:3, :3]
        t_BD = self.T_BD0[:3, 3] + x[0:3]
        R_KC = exp_so3(x[9:12]) @ self.T_KC0[:3, :3]
        t_KC = self.T_KC0[:3, 3] + x[6:9]
        Jl_BD = so3_left_jacobian(x[3:6])
        Jl_KC = so3_left_jacobian(x[9:12])
        zeta = np.zeros((self.data.n, 3)) if structural else self.zetas(x)
        r = np.zeros(self.n_residuals)
        J = np.zeros((self.n_residuals, self.n_params))
        sp, sr = self.sigma_p, self.sigma_r
        row = 0
        for i in range(self.data.n):
            R_hat = R_BD @ self.R_fix_ref[i] @ exp_so3(zeta[i]) @ R_KC.T
            u = R_BD @ self.q[i] - R_hat @ t_KC
            t_hat = u + t_BD
            if structural:
                e = np.zeros(3)
            else:
                r[row : row + 3] = (self.t_meas[i] - t_hat) / sp
                e = log_so3(R_hat.T @ self.R_meas[i])
                r[row + 3 : row + 6] = e / sr
            Jinv = so3_left_jacobian_inv(e)
            P = slice(row, row + 3)
            Q = slice(row + 3, row + 6)
            J[P, 0:3] = -np.eye(3) / sp
            J[P, 3:6] = hat(u) @ Jl_BD / sp
            J[P, 6:9] = R_hat / sp
            J[P, 9:12] = R_hat @ hat(t_KC) @ Jl_KC / sp
            J[Q, 3:6] = -Jinv @ R_hat.T @ Jl_BD / sr
            J[Q, 9:12] = Jinv @ Jl_KC / sr
            c = self.nuis_col[i]
            if c >= 0:
                Jr = so3_right_jacobian(zeta[i])
                J[P, c : c + 3] = -R_hat @ hat(t_KC) @ R_KC @ Jr / sp
                J[Q, c : c + 3] = -Jinv @ R_KC @ Jr / sr
            row += 6
        for i in np.flatnonzero(self.has_prior_rows):
            c = self.nuis_col[i]
            r[row : row + 3] = zeta[i] / self.sigma_fix
            J[row : row + 3, c : c + 3] = np.eye(3) / self.sigma_fix
            row += 3
        if self.prior is not None:
            pr = self.prior
            r[row : row + 3] = (t_KC - pr.T_tracker_tcp[:3, 3]) / pr.sigma_position_m
            J[row : row + 3, 6:9] = np.eye(3) / pr.sigma_position_m
            row += 3
            if pr.sigma_rotation_rad:
                e = log_so3(R_KC @ pr.T_tracker_tcp[:3, :3].T)
                r[row : row + 3] = e / pr.sigma_rotation_rad
                J[row : row + 3, 9:12] = so3_left_jacobian_inv(e) @ Jl_KC / pr.sigma_rotation_rad
                row += 3
        if self.gauge is not None:
            k = self.gauge.shape[0]
            r[row : row + k] = GAUGE_WEIGHT * (self.gauge @ x[:N_MAIN])
            J[row : row + k, :N_MAIN] = GAUGE_WEIGHT * self.gauge
            row += k
        if structural:
            r[:] = 0.0
        return r, J

    def _cached(self, x: F64) -> tuple[F64, F64]:
        key = np.asarray(x, dtype=float).tobytes()
        if getattr(self, "_cache_key", None) != key:
            self._cache_key = key
            self._cache_val = self.residual_and_jacobian(np.asarray(x, dtype=float))
        return self._cache_val

    def residual(self, x: F64) -> F64:
        """Whitened residual (the optimiser's ``fun``; shares one evaluation with :meth:`jacobian`)."""
        return self._cached(x)[0].copy()

    def jacobian(self, x: F64) -> F64:
        return self._cached(x)[1].copy()

    def sample_row_blocks(self) -> list[NDArray[np.int_]]:
        """Row indices of each sample's residuals (its 6 tracker rows and its scatter-prior rows)."""
        blocks = [list(range(6 * i, 6 * i + 6)) for i in range(self.data.n)]
        row = 6 * self.data.n
        for i in np.flatnonzero(self.has_prior_rows):
            blocks[i] += [row, row + 1, row + 2]
            row += 3
        return [np.array(b) for b in blocks]

    def design_jacobians(self, x: F64) -> tuple[F64, F64]:
        """(J_main, J_nuisance) of the noise-free design for the identifiability analysis.

        Fixture samples count with their nominal orientation taken as exact (the random scatter is
        not a design); free-orientation samples keep their orientation columns as nuisance.
        """
        _, J = self.residual_and_jacobian(x, structural=True)
        rows = np.concatenate(
            [
                np.arange(6 * self.data.n),
                np.arange(self.n_residuals - self._n_tcp_prior_rows(), self.n_residuals),
            ]
        )
        J = J[rows]
        free_cols = [
            np.arange(self.nuis_col[i], self.nuis_col[i] + 3)
            for i in range(self.data.n)
            if self.nuis_col[i] >= 0 and not self.data.orientation_known[i]
        ]
        cols = np.concatenate(free_cols) if free_cols else np.zeros(0, dtype=int)
        return J[:, :N_MAIN], J[:, cols]

    def _n_tcp_prior_rows(self) -> int:
        if self.prior is None:
            return 0
        return 3 + (3 if self.prior.sigma_rotation_rad else 0)


def seed_style_errors(data: ViveDeskData, T_BD: F64, T_KC: F64, R_desktop_tcp: F64 | None = None) -> F64:
    """(N, 6) seed 001 step-3 errors: TCP position via tracker minus via desk (base frame, m) and the
    rotation vector of R_expected^T R_measured (rad), with the nominal fixture orientations unless
    *R_desktop_tcp* (N, 3, 3) is given (free-orientation samples need their estimated orientation)."""
    R_all = data.R_desktop_tcp if R_desktop_tcp is None else R_desktop_tcp
    out = np.zeros((data.n, 6))
    for i in range(data.n):
        T_exp = T_BD @ T_from_Rt(R_all[i], data.tcp_positions_desktop[i])
        T_mea = data.T_base_tracker[i] @ T_KC
        out[i, :3] = T_mea[:3, 3] - T_exp[:3, 3]
        out[i, 3:] = log_so3(T_exp[:3, :3].T @ T_mea[:3, :3])
    return out
