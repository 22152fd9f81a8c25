"""What the catalog's candidates ask a kinematic gap problem for: design columns at the current model.

A mixin of :class:`.problem.KinematicGapProblem`: the current state (the joints each sample's
measurement shows, the actual joints and chain values with the accepted effects and the measured
points), the whitened derivative of the measurements with respect to a robot candidate's values or a
measurement-side effect, the joint Jacobian at the measured point, and the gravity torque. Range
effects already in the model turn every column by their output Jacobian. For the end test
(:mod:`plugins.model_gap.core.end_test`): each joint's error direction (an out-of-catalog joint error
is that direction times some function of a feature) and the groups of replicate measurements.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from plugins.robot.effects.measurement import range_distortion_jacobian

F64 = NDArray[np.float64]


class CandidateColumns:
    """Design columns for the candidates (see the module docstring); needs the problem's state."""

    model: Any
    nominal: Any
    accepted: list
    points: Any
    sigma: F64
    q: F64
    qd: F64 | None
    ctx: Any
    n_samples: int

    def _split(self, accepted: list) -> tuple[list, dict[str, float]]:  # provided by the problem
        raise NotImplementedError

    def _robot(self, model: Any, effects: list, points: Any) -> Any:  # provided by the problem
        raise NotImplementedError

    def current_state(self) -> tuple[F64, F64, F64]:
        """``(q_seen, q_actual, values_actual)`` of the current model for every sample."""
        robot, meas = self._split(self.accepted)
        lat = meas.get("time_latency", 0.0)
        q = self.q - lat * self.qd if (lat and self.qd is not None) else self.q
        rw = self._robot(self.model, [c.effect(v) for c, v in robot], self.points)
        qa, va = rw.actual_state(q, self.ctx)
        return q, qa, va

    def _output_jacobian(self) -> F64:
        """``(N, 3, 3)``: derivative of the measured point w.r.t. the true point (range effects)."""
        _, meas = self._split(self.accepted)
        if "depth_scale" not in meas and "depth_bias" not in meas:
            return np.broadcast_to(np.eye(3), (self.n_samples, 3, 3))
        _, qa, va = self.current_state()
        p = self.model.fk(qa, va)[:, :3, 3]
        return range_distortion_jacobian(p, meas.get("depth_scale", 0.0), meas.get("depth_bias", 0.0))

    def robot_columns(self, candidate, values: F64) -> F64:
        """Whitened ``(N, 3, k)`` derivative of the measurements w.r.t. a robot candidate's values."""
        robot, _ = self._split(self.accepted)
        q, _, _ = self.current_state()
        effects = [c.effect(c.jac_values(v)) for c, v in robot] + [candidate.effect(candidate.jac_values(values))]
        rw = self._robot(self.model, effects, self.points)
        jmap = candidate.jac_map(candidate.jac_values(values))
        J = rw.effect_jacobian(len(rw.effects) - 1, q, self.ctx)[:, :3, :] @ jmap
        return (self._output_jacobian() @ J) / self.sigma[:, None, None]

    def measurement_columns(self, name: str) -> F64:
        """Whitened ``(N, 3, 1)`` column of a measurement-side effect at the current state."""
        _, qa, va = self.current_state()
        if name == "time_latency":
            _, Jq = self.model.chain.screw_jacobian(qa, va)
            col = self._output_jacobian() @ (-np.einsum("nij,nj->ni", Jq[:, :3, :], self.qd))[:, :, None]
        else:
            p = self.model.fk(qa, va)[:, :3, 3]
            col = (p if name == "depth_scale" else p / np.linalg.norm(p, axis=1, keepdims=True))[:, :, None]
        return col / self.sigma[:, None, None]

    def joint_position_jacobian(self) -> F64:
        """``(N, 3, n)`` derivative of the measured point w.r.t. each joint angle (SI)."""
        _, qa, va = self.current_state()
        _, Jq = self.model.chain.screw_jacobian(qa, va)
        return self._output_jacobian() @ Jq[:, :3, :]

    @property
    def noise_source(self) -> str:
        """given | data column | estimated (:class:`.problem.ProblemConfig`)."""
        return str(self.cfg.noise_source)  # type: ignore[attr-defined]

    def error_directions(self) -> list[tuple[str, str, F64]]:
        """``(name, label, (N, 3) SI)`` per joint: the measured point's displacement per radian of that joint's
        angle error, where an error the catalog lacks would act (a cable pulling on the wrist)."""
        J = self.joint_position_jacobian()
        return [(f"joint{j + 1}", f"joint {j + 1} angle error", J[:, :, j]) for j in range(J.shape[2])]

    def replicate_groups(self) -> list[np.ndarray]:
        """Row indices of the replicate measurements: the same commanded joints (to 1e-6 rad), approach
        directions, payload and measured point, measured within the same minute; groups of >= 2 rows."""
        s = self.data.samples  # type: ignore[attr-defined]
        parts = [np.round(self.q / 1e-6).astype(np.int64)]
        for extra in (s.direction, s.payload_kg, None if s.t_s is None else np.floor(np.asarray(s.t_s) / 60.0)):
            if extra is not None:
                parts.append(
                    np.round(np.asarray(extra, dtype=float).reshape(self.n_samples, -1) * 1e6).astype(np.int64)
                )
        key = np.concatenate(parts, axis=1)
        names = s.point if s.point is not None else np.full(self.n_samples, "")
        groups: dict[tuple, list[int]] = {}
        for i in range(self.n_samples):
            groups.setdefault((str(names[i]), *key[i].tolist()), []).append(i)
        return [np.array(g) for g in groups.values() if len(g) >= 2]

    def gravity_torque(self) -> F64 | None:
        if self.model.links is None:
            return None
        payload = 0.0 if self.ctx.payload_kg is None else self.ctx.payload_kg
        return self.nominal.gravity_torque(self.q, payload_kg=payload)
