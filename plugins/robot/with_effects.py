"""The "true" robot: a nominal :class:`RobotModel` plus robot-side effects, and its derivatives.

The simulated controller reaches commanded poses in nominal-model terms; where the TCP really is
comes from this class, which is how calibration error shows up in the simulated cell. The same class
is the augmented model the model-gap workflow fits: :meth:`RobotWithEffects.effect_jacobian`
gives the derivative of the predicted pose with respect to one effect's parameter vector, so any
catalog effect can be fitted by least squares against measurements.

Prediction for commanded joints ``q`` and a :class:`SampleContext`::

    q_actual      = q + sum_e e.joint_offsets(nominal, q, ctx)
    values_actual = nominal.param_values + sum_e e.param_offsets(nominal, q, ctx)
    T_world_tcp   = nominal.fk(q_actual, values_actual)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from plugins.robot.chain import JacobianFrame
from plugins.robot.effects.base import RobotEffect, SampleContext
from plugins.robot.kinematics import RobotModel

F64 = NDArray[np.float64]


class RobotWithEffects:
    """Nominal model + effects (see module docstring). Effects are validated against the model."""

    def __init__(self, nominal: RobotModel, effects: Sequence[RobotEffect] = ()) -> None:
        self.nominal = nominal
        self.effects: tuple[RobotEffect, ...] = tuple(effects)
        for e in self.effects:
            if not isinstance(e, RobotEffect):
                raise TypeError(f"expected a RobotEffect, got {type(e).__name__}")
            e.validate(nominal)

    def with_effects(self, effects: Sequence[RobotEffect]) -> RobotWithEffects:
        return RobotWithEffects(self.nominal, effects)

    def replace_effect(self, index: int, effect: RobotEffect) -> RobotWithEffects:
        effects = list(self.effects)
        effects[index] = effect
        return RobotWithEffects(self.nominal, effects)

    # ----------------------------------------------------------------------------- prediction

    def _prepare(self, q: ArrayLike, ctx: SampleContext | None) -> tuple[F64, bool, SampleContext]:
        Q, single = self.nominal.check_joints(q)
        c = (ctx or SampleContext()).for_samples(Q.shape[0], self.nominal.dof)
        for e in self.effects:
            e.check_context(c)
        return Q, single, c

    def _joint_offsets(self, effects, Q: F64, ctx: SampleContext) -> F64:
        dq = np.zeros_like(Q)
        for e in effects:
            d = e.joint_offsets(self.nominal, Q, ctx)
            if d is not None:
                dq = dq + d
        return dq

    def _param_offsets(self, effects, Q: F64, ctx: SampleContext) -> F64:
        dv = np.zeros(len(self.nominal.param_names))
        for e in effects:
            d = e.param_offsets(self.nominal, Q, ctx)
            if d is not None:
                dv = dv + d  # (P,) + (N, P) broadcasts to per-sample values
        return dv

    def actual_state(self, q: ArrayLike, ctx: SampleContext | None = None) -> tuple[F64, F64]:
        """``(q_actual (N, n), values_actual (P,) or (N, P))`` for commanded ``q``."""
        Q, _, c = self._prepare(q, ctx)
        return Q + self._joint_offsets(self.effects, Q, c), self.nominal.param_values + self._param_offsets(
            self.effects, Q, c
        )

    def actual_joints(self, q: ArrayLike, ctx: SampleContext | None = None) -> F64:
        """True joint angles for commanded ``q``: ``(n,)`` or ``(N, n)``."""
        Q, single, c = self._prepare(q, ctx)
        qa = Q + self._joint_offsets(self.effects, Q, c)
        return qa[0] if single else qa

    def fk(self, q: ArrayLike, ctx: SampleContext | None = None, *, frame: str = "world") -> F64:
        """True TCP pose for commanded ``q``: ``(4, 4)`` or ``(N, 4, 4)``."""
        Q, single, _ = self._prepare(q, ctx)
        qa, va = self.actual_state(Q, ctx)
        T = self.nominal.fk(qa, va, frame=frame)  # type: ignore[arg-type]
        return T[0] if single else T

    def tool_points(self, q: ArrayLike, ctx: SampleContext | None = None, point_tcp: ArrayLike = (0, 0, 0)) -> F64:
        """True world position of a point of the TCP frame: ``(3,)`` or ``(N, 3)``."""
        T = self.fk(q, ctx)
        p = np.asarray(point_tcp, dtype=float).reshape(3)
        return T[..., :3, :3] @ p + T[..., :3, 3]

    def joints_reaching(
        self, T_world_tcp: ArrayLike, q_seed: ArrayLike | None = None, *, tol_m: float = 1e-9, max_iter: int = 20
    ) -> F64:
        """Commanded joints at which the TRUE TCP is at ``T_world_tcp`` (what jogging the real robot there gives).

        This is how a pose is taught on a robot with errors: the controller then reports the nominal
        pose of these joints (``nominal.fk(q)``), not ``T_world_tcp``. Newton on the true pose from the
        nominal inverse kinematics, with the nominal geometric Jacobian (the effects are small).
        Raises ValueError when the target is not reached to ``tol_m`` (and 1e-9 rad).
        """
        T_t = np.asarray(T_world_tcp, dtype=float)
        ik = self.nominal.ik(T_t, q_seed)
        if not ik.success or ik.q is None:
            raise ValueError(f"the nominal model cannot reach the pose: {ik.reason}")
        q = np.asarray(ik.q, dtype=float)
        for _ in range(max_iter):
            T = self.fk(q)
            dp = T_t[:3, 3] - T[:3, 3]
            dw = Rotation.from_matrix(T_t[:3, :3] @ T[:3, :3].T).as_rotvec()
            if np.linalg.norm(dp) < tol_m and np.linalg.norm(dw) < 1e-9:
                return q
            J = self.nominal.jacobian(q, frame="base")  # world coordinates, v of the TCP origin
            q = q + np.linalg.lstsq(J, np.concatenate([dp, dw]), rcond=None)[0]
        raise ValueError(f"the true robot did not reach the pose within {max_iter} Newton steps")

    # ----------------------------------------------------------------------------- fitting support

    def effect_jacobian(
        self,
        index: int,
        q: ArrayLike,
        ctx: SampleContext | None = None,
        *,
        frame: JacobianFrame = "base",
        point_tcp: ArrayLike | None = None,
        rel_step: float = 1e-6,
    ) -> F64:
        """``(N, 6, k)``: derivative of the true pose w.r.t. effect ``index``'s parameter vector.

        Chain rule through the analytic joint and parameter Jacobians at the current true state; the
        effect's own offsets are differentiated by central differences of ``unpack`` (exact up to
        rounding for the effects that are linear in their parameters).
        """
        Q, _, c = self._prepare(q, ctx)
        effect = self.effects[index]
        qa, va = self.actual_state(Q, c)
        pt = None if point_tcp is None else np.asarray(point_tcp, dtype=float).reshape(3)
        _, Jq = self.nominal.chain.screw_jacobian(qa, va, frame=frame, point_tcp=pt)
        _, Jp = self.nominal.chain.screw_jacobian(qa, va, columns="params", frame=frame, point_tcp=pt)
        x0 = effect.pack()
        k = x0.size
        out = np.zeros((Q.shape[0], 6, k))
        for i in range(k):
            h = max(rel_step * max(1.0, abs(x0[i])), 1e-12)
            xp, xm = x0.copy(), x0.copy()
            xp[i] += h
            xm[i] -= h
            ep, em = effect.unpack(xp), effect.unpack(xm)
            ddq = (self._joint_offsets([ep], Q, c) - self._joint_offsets([em], Q, c)) / (2 * h)
            ddv = (self._param_offsets([ep], Q, c) - self._param_offsets([em], Q, c)) / (2 * h)
            col = np.einsum("nij,nj->ni", Jq, ddq)
            if ddv.ndim == 1:
                col += Jp @ ddv
            else:
                col += np.einsum("nij,nj->ni", Jp, ddv)
            out[:, :, i] = col
        return out

    def describe(self) -> list[dict[str, Any]]:
        """JSON-ready list of the effects and their parameters (for ``truth/`` records)."""
        return [e.describe() for e in self.effects]
