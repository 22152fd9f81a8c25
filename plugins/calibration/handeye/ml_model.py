"""The errors-in-variables measurement model of hand-eye calibration: residuals and Jacobians.

Model: every sample obeys ``A_i X B_i = Y`` exactly for the TRUE robot pose ``M_i`` and camera
pose ``B_i`` (see ``problem``); both are measured with noise (see ``noise``). Maximum likelihood
therefore estimates X, Y *and* the true robot poses ``M_i`` (nuisance parameters), with

    robot residual   e_M,i = M~_i  (-)  M_i                       (6, decoupled difference)
    camera residual  e_B,i = B~_i  (-)  X^-1 A_i(M_i)^-1 Y         (6)

each whitened by its noise: the robot's by its per-axis sigmas, the camera's by the shared per-axis
sigmas or, when the noise gives each sample its own camera covariance ``C_i``
(``NoiseModel.camera_covariances``), by ``W_i = L_i^-1`` (``C_i = L_i L_i^T``): ``|W_i e|^2 =
e^T C_i^-1 e``, and the same ``W_i`` whitens the sample's camera Jacobian rows. Minimising the sum
of squares is the exact ML estimate under Gaussian noise of both poses (no linearisation of the
noise into the chain); each sample has 12 residuals and 6 nuisance parameters, so its minimised
cost is chi-square with 6 degrees of freedom. When the robot is declared exact the M_i are fixed
at the measurements and only the camera residuals remain (same 6 degrees of freedom per sample).

Parameters are decoupled perturbations (:mod:`engine.transforms`) of reference poses: ``x = (dX, dY, dM_1..dM_n)``.
Jacobians are analytic (chain of ``engine.transforms.d_*`` operators) and carry the exact chart factor
``J_l(dphi)``; at ``x = 0`` the columns are the perturbations the covariance is reported in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import sparse

from engine.transforms import (
    d_inverse,
    d_product_left,
    d_product_right,
    inv,
    pose_delta,
    retract,
    so3_left_jacobian,
    so3_right_jacobian_inv,
)
from plugins.calibration.handeye.noise import NoiseModel, camera_whitening
from plugins.calibration.handeye.problem import Setup

F64 = NDArray[np.float64]

__all__ = ["EivModel", "EivState"]


@dataclass
class EivState:
    """Poses at one parameter vector, with the unwhitened residuals and block Jacobians."""

    X: F64
    Y: F64
    M: F64  # (n, 4, 4) robot poses (estimated, or the measurements when the robot is exact)
    B_model: F64  # (n, 4, 4)
    e_robot: F64  # (n, 6) decoupled M~ (-) M      (zeros when the robot is exact)
    e_camera: F64  # (n, 6) decoupled B~ (-) B_model
    J_glob: F64 | None = None  # (n, r, 12) whitened d residual / d (X, Y)   (r = 12 or 6)
    J_nuis: F64 | None = None  # (n, r, 6)  whitened d residual / d M_i (robot-free model only)


def _blockdiag_I_J(Jrot: F64) -> F64:
    n = Jrot.shape[0]
    D = np.zeros((n, 6, 6))
    D[:, :3, :3] = np.eye(3)
    D[:, 3:, 3:] = Jrot
    return D


class EivModel:
    """Residuals and Jacobians of the errors-in-variables model around reference poses."""

    def __init__(
        self,
        setup: Setup,
        M_meas: F64,
        B_meas: F64,
        noise: NoiseModel,
        X_ref: F64,
        Y_ref: F64,
        M_ref: F64 | None = None,
        *,
        camera_axes: bool = False,
    ) -> None:
        self.setup = setup
        # the camera noise's variance components: one per axis (camera_axes) or one for its
        # translation and one for its rotation (``variance.group_rows``)
        self.camera_axes = camera_axes
        self.M_meas = M_meas
        self.B_meas = B_meas
        self.n = int(M_meas.shape[0])
        self.robot_free = not noise.robot.is_exact
        self.w_robot = 1.0 / noise.robot.sigmas6() if self.robot_free else np.zeros(6)
        # the camera's whitening: per axis, shared (w_camera), or each sample's own W_i = L_i^-1 (W_camera)
        self.camera_sigmas = noise.camera.sigmas6()
        self.w_camera = 1.0 / self.camera_sigmas
        cov = noise.camera_covariances
        if cov is not None and len(cov) != self.n:
            raise ValueError(f"{len(cov)} camera covariances for {self.n} samples: one per sample is needed")
        self.W_camera: F64 | None = None if cov is None else camera_whitening(cov)
        self.X_ref = X_ref.reshape(1, 4, 4)
        self.Y_ref = Y_ref.reshape(1, 4, 4)
        self.M_ref = (M_meas if M_ref is None else M_ref).copy()
        self.rows_per_sample = 12 if self.robot_free else 6
        self.n_params = 12 + (6 * self.n if self.robot_free else 0)
        self._cache_x: F64 | None = None
        self._cache: EivState | None = None

    # ------------------------------------------------------------------ evaluation
    def state(self, x: F64, *, jacobian: bool = False) -> EivState:
        x = np.asarray(x, dtype=float)
        if (
            self._cache is not None
            and self._cache_x is not None
            and np.array_equal(x, self._cache_x)
            and (self._cache.J_glob is not None or not jacobian)
        ):
            return self._cache
        dX, dY = x[:6], x[6:12]
        X = retract(self.X_ref, dX)[0]
        Y = retract(self.Y_ref, dY)[0]
        if self.robot_free:
            dM = x[12:].reshape(self.n, 6)
            M = retract(self.M_ref, dM)
            e_robot = pose_delta(self.M_meas, M)
        else:
            dM = np.zeros((self.n, 6))
            M = self.M_ref
            e_robot = np.zeros((self.n, 6))
        C = inv(M) if self.setup == "eye_in_hand" else M
        Xi = inv(X)
        D = C @ Y
        B_model = Xi @ D
        e_camera = pose_delta(self.B_meas, B_model)
        st = EivState(X, Y, M, B_model, e_robot, e_camera)
        if jacobian:
            dEB = -_blockdiag_I_J(so3_right_jacobian_inv(e_camera[:, 3:]))
            K_X = _blockdiag_I_J(so3_left_jacobian(dX[None, 3:]))[0]
            K_Y = _blockdiag_I_J(so3_left_jacobian(dY[None, 3:]))[0]
            dB_dX = d_product_left(Xi, D) @ d_inverse(X)[0]
            dB_dY = d_product_right(Xi)[0] @ d_product_right(C)
            wc = self.whiten_camera
            Jg_cam = np.concatenate([wc(dEB @ dB_dX @ K_X), wc(dEB @ dB_dY @ K_Y)], axis=2)
            if self.robot_free:
                K_M = _blockdiag_I_J(so3_left_jacobian(dM[:, 3:]))
                dC_dM = d_inverse(M) if self.setup == "eye_in_hand" else np.broadcast_to(np.eye(6), (self.n, 6, 6))
                dB_dM = d_product_right(Xi)[0] @ d_product_left(C, Y) @ dC_dM
                dEM = -_blockdiag_I_J(so3_right_jacobian_inv(e_robot[:, 3:]))
                Wr = self.w_robot[None, :, None]
                st.J_glob = np.concatenate([np.zeros((self.n, 6, 12)), Jg_cam], axis=1)
                st.J_nuis = np.concatenate([Wr * (dEM @ K_M), wc(dEB @ dB_dM @ K_M)], axis=1)
            else:
                st.J_glob = Jg_cam
        self._cache_x, self._cache = x.copy(), st
        return st

    @property
    def camera_per_sample(self) -> bool:
        """True when each sample's camera residual is whitened by its own covariance."""
        return self.W_camera is not None

    def whiten_camera(self, A: F64) -> F64:
        """Camera rows whitened: ``A`` the ``(n, 6)`` residuals or ``(n, 6, k)`` Jacobian blocks."""
        if self.W_camera is None:
            return A * (self.w_camera if A.ndim == 2 else self.w_camera[:, None])
        if A.ndim == 2:
            return np.einsum("nij,nj->ni", self.W_camera, A)
        return self.W_camera @ A

    def camera_logdet(self) -> F64:
        """``(n,)`` log det of each sample's camera covariance."""
        if self.W_camera is None:
            return np.full(self.n, 2.0 * float(np.sum(np.log(self.camera_sigmas))))
        return -2.0 * np.sum(np.log(np.diagonal(self.W_camera, axis1=1, axis2=2)), axis=1)

    def whitened(self, st: EivState) -> F64:
        """(n, r) whitened residuals of a state (robot rows first when the robot is free)."""
        cam = self.whiten_camera(st.e_camera)
        if not self.robot_free:
            return cam
        return np.concatenate([st.e_robot * self.w_robot, cam], axis=1)

    # ------------------------------------------------------------------ least-squares plumbing
    def residual_vector(self, x: F64, sqrt_w: F64) -> F64:
        return (self.whitened(self.state(x)) * sqrt_w[:, None]).reshape(-1)

    def jacobian_matrix(self, x: F64, sqrt_w: F64, *, as_sparse: bool) -> F64 | sparse.csr_matrix:
        st = self.state(x, jacobian=True)
        assert st.J_glob is not None
        r, n = self.rows_per_sample, self.n
        Jg = st.J_glob * sqrt_w[:, None, None]
        if not self.robot_free:
            return Jg.reshape(n * r, 12)
        assert st.J_nuis is not None
        Jn = st.J_nuis * sqrt_w[:, None, None]
        if as_sparse:
            glob = sparse.csr_matrix(Jg.reshape(n * r, 12))
            nuis = sparse.block_diag(list(Jn), format="csr")
            return sparse.hstack([glob, nuis], format="csr")
        J = np.zeros((n * r, self.n_params))
        J[:, :12] = Jg.reshape(n * r, 12)
        for i in range(n):
            J[i * r : (i + 1) * r, 12 + 6 * i : 18 + 6 * i] = Jn[i]
        return J

    def recentred(self, x: F64) -> EivModel:
        """A model of the same data whose reference poses are the poses at x (so x becomes 0)."""
        st = self.state(x)
        new = EivModel.__new__(EivModel)
        new.__dict__.update(self.__dict__)
        new.X_ref, new.Y_ref, new.M_ref = st.X.reshape(1, 4, 4), st.Y.reshape(1, 4, 4), st.M.copy()
        new._cache_x, new._cache = None, None
        return new

    def with_noise(self, noise: NoiseModel) -> EivModel:
        """Same data and reference poses, other noise model."""
        return EivModel(
            self.setup,
            self.M_meas,
            self.B_meas,
            noise,
            self.X_ref[0],
            self.Y_ref[0],
            self.M_ref,
            camera_axes=self.camera_axes,
        )

    # ------------------------------------------------------------------ information
    def information_xy(self, st: EivState, weights: F64) -> F64:
        """Fisher information of (X, Y) (12 x 12) with the nuisance robot poses eliminated (Schur)."""
        assert st.J_glob is not None
        info = np.zeros((12, 12))
        for i in np.flatnonzero(weights > 0):
            G = st.J_glob[i]
            if self.robot_free:
                assert st.J_nuis is not None
                N = st.J_nuis[i]
                NtN = N.T @ N
                GtN = G.T @ N
                info += weights[i] * (G.T @ G - GtN @ np.linalg.solve(NtN, GtN.T))
            else:
                info += weights[i] * (G.T @ G)
        return info

    def hat_diagonal(self, st: EivState, weights: F64) -> F64:
        """Diagonal of the hat matrix ``J (J^T J)^-1 J^T`` per sample, ``(n, r)`` (zeros for weight 0).

        Uses the block structure: ``H = P_N + (I - P_N) G S^-1 G^T (I - P_N)`` with ``P_N`` the
        per-sample projector onto the nuisance columns and ``S`` the Schur complement
        (:meth:`information_xy`). ``1 - diag(H)`` are the redundancy numbers of the residuals.
        """
        assert st.J_glob is not None
        r = self.rows_per_sample
        h = np.zeros((self.n, r))
        S_inv = np.linalg.pinv(self.information_xy(st, weights))
        for i in np.flatnonzero(weights > 0):
            G = st.J_glob[i] * np.sqrt(weights[i])
            if self.robot_free:
                assert st.J_nuis is not None
                N = st.J_nuis[i] * np.sqrt(weights[i])
                P = N @ np.linalg.solve(N.T @ N, N.T)
                G = G - P @ G
                h[i] = np.diag(P)
            h[i] += np.einsum("ij,jk,ik->i", G, S_inv, G)
        return h
