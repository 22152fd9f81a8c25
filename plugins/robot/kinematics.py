"""Serial robot model: forward kinematics, Jacobians, gravity torque and limits, vectorised over poses.

:class:`RobotModel` is what recipes load by name (``ur5e``, ``abb_irb120``; see
:mod:`plugins.robot.model_file`), what the simulated controller drives, what the robot-side effects
perturb, and what kinematic calibration and the model-gap workflow fit. It wraps a
:class:`~plugins.robot.chain.KinematicChain` (one named value per elementary motion) with the joint
limits, speeds, link masses and frames.

Frames: ``fk`` returns ``T_world_tcp = T_world_base @ T_base_flange(q) @ T_flange_tcp``. For the
shipped models ``T_world_base`` is the identity, so world = robot base (the frame the vendor
controller reports poses in). ``frame="base"`` strips ``T_world_base``.

Shapes: joint arrays are ``(n,)`` for one configuration or ``(N, n)`` for many; results follow
(``fk``: ``(4, 4)`` or ``(N, 4, 4)``; ``jacobian``: ``(6, n)`` or ``(N, 6, n)``). Jacobian twist
order is ``(v, w)`` like :mod:`engine.transforms`; see :mod:`plugins.robot.chain` for the frames.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.transforms import as_transform, inv
from plugins.robot.chain import ChainOp, JacobianFrame, KinematicChain
from plugins.robot.conventions import CONVENTIONS, DHRow, PoeJoint, build_chain, dh_to_mdh, mdh_to_dh
from plugins.robot.ik import IKResult, solve_ik

F64 = NDArray[np.float64]
STANDARD_GRAVITY = 9.80665


@dataclass(frozen=True)
class JointSpec:
    """Limits of one revolute joint (rad, rad/s, rad/s^2)."""

    name: str
    lower: float
    upper: float
    max_speed: float
    max_accel: float

    def __post_init__(self) -> None:
        vals = (self.lower, self.upper, self.max_speed, self.max_accel)
        if not all(np.isfinite(v) for v in vals):
            raise ValueError(f"{self.name}: limits must be finite, got {vals}")
        if not self.lower < self.upper:
            raise ValueError(f"{self.name}: lower limit {self.lower} must be below upper {self.upper}")
        if self.max_speed <= 0 or self.max_accel <= 0:
            raise ValueError(f"{self.name}: max_speed and max_accel must be positive")


@dataclass(frozen=True)
class LinkInertia:
    """Mass (kg) and centre of mass (m) of the link moved by joint *i*, in that link's frame.

    The link frame is the frame at the end of the joint's group in the chain: DH frame *i* for
    ``dh``, Craig frame *i* for ``mdh``, the joint frame on axis *i* for ``poe``.
    """

    mass_kg: float
    com_link: tuple[float, float, float]


class RobotModel:
    """A serial revolute robot: chain + joint limits + optional link masses (see module docstring)."""

    def __init__(
        self,
        name: str,
        convention: str,
        chain: KinematicChain,
        joints: Sequence[JointSpec],
        *,
        links: Sequence[LinkInertia] | None = None,
        gravity_world: ArrayLike = (0.0, 0.0, -STANDARD_GRAVITY),
        description: str = "",
        sources: Sequence[str] = (),
        home: ArrayLike | None = None,
    ) -> None:
        if convention not in CONVENTIONS:
            raise ValueError(f"unknown convention {convention!r}; use one of {', '.join(CONVENTIONS)}")
        if len(joints) != chain.n_joints:
            raise ValueError(f"chain has {chain.n_joints} joints but {len(joints)} joint specs were given")
        if links is not None and len(links) != chain.n_joints:
            raise ValueError(f"need one link inertia per joint ({chain.n_joints}), got {len(links)}")
        g = np.asarray(gravity_world, dtype=float).reshape(3)
        if not np.all(np.isfinite(g)):
            raise ValueError("gravity vector contains NaN or infinity")
        self.name = name
        self.convention = convention
        self.chain = chain
        self.joints: tuple[JointSpec, ...] = tuple(joints)
        self.links: tuple[LinkInertia, ...] | None = None if links is None else tuple(links)
        self.gravity_world: F64 = g
        self.description = description
        self.sources: tuple[str, ...] = tuple(sources)
        self.lower: F64 = np.array([j.lower for j in self.joints])
        self.upper: F64 = np.array([j.upper for j in self.joints])
        self.max_speed: F64 = np.array([j.max_speed for j in self.joints])
        self.max_accel: F64 = np.array([j.max_accel for j in self.joints])
        self.home: F64 = np.zeros(self.dof) if home is None else self.check_joints(home)[0][0]

    # ----------------------------------------------------------------------------- basics

    @property
    def dof(self) -> int:
        return self.chain.n_joints

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def param_names(self) -> tuple[str, ...]:
        """Names of the chain parameters (``joint2.a``, ``base.tz`` ...), the order of ``param_values``."""
        return self.chain.param_names

    @property
    def param_values(self) -> F64:
        return self.chain.values

    def __repr__(self) -> str:
        return f"RobotModel({self.name!r}, convention={self.convention!r}, dof={self.dof})"

    # ----------------------------------------------------------------------------- validation

    def check_joints(self, q: ArrayLike, *, name: str = "q") -> tuple[F64, bool]:
        """Validate joint angles: returns ``(Q (N, n), was_single)`` or raises ValueError."""
        try:
            Q = np.asarray(q, dtype=float)
        except (TypeError, ValueError) as e:
            raise ValueError(f"{name} must be numeric joint angles in rad: {e}") from None
        single = Q.ndim == 1
        if Q.ndim not in (1, 2) or Q.shape[-1] != self.dof:
            raise ValueError(
                f"{self.name} has {self.dof} joints: {name} must have shape ({self.dof},) or "
                f"(N, {self.dof}), got {Q.shape}"
            )
        Q = Q.reshape(-1, self.dof)
        bad = ~np.all(np.isfinite(Q), axis=1)
        if np.any(bad):
            rows = np.flatnonzero(bad)[:5].tolist()
            raise ValueError(f"{name} contains NaN or infinity (rows {rows})")
        return Q, single

    def check_values(self, values: ArrayLike | None, n: int) -> F64 | None:
        """Validate a chain-parameter override: ``None``, ``(P,)`` or ``(n, P)``."""
        if values is None:
            return None
        V = np.asarray(values, dtype=float)
        P = len(self.param_names)
        if V.shape not in ((P,), (n, P)):
            raise ValueError(f"parameter values must have shape ({P},) or ({n}, {P}), got {V.shape}")
        if not np.all(np.isfinite(V)):
            raise ValueError("parameter values contain NaN or infinity")
        return V

    def within_limits(self, q: ArrayLike, margin: float = 0.0) -> NDArray[np.bool_] | bool:
        """True where every joint is inside ``[lower + margin, upper - margin]``."""
        Q, single = self.check_joints(q)
        ok = np.all((self.lower + margin <= Q) & (self.upper - margin >= Q), axis=1)
        return bool(ok[0]) if single else ok

    def limit_violations(self, q: ArrayLike) -> list[str]:
        """Human-readable list of the joints of one configuration that are out of limits (degrees)."""
        Q, _ = self.check_joints(q)
        out = []
        for j, (v, lo, hi) in enumerate(zip(Q[0], self.lower, self.upper, strict=True)):
            if v < lo or v > hi:
                out.append(
                    f"{self.joint_names[j]} = {np.degrees(v):.3f} deg outside "
                    f"[{np.degrees(lo):.1f}, {np.degrees(hi):.1f}] deg"
                )
        return out

    # ----------------------------------------------------------------------------- kinematics

    def fk(
        self,
        q: ArrayLike,
        values: ArrayLike | None = None,
        *,
        frame: Literal["world", "base"] = "world",
    ) -> F64:
        """TCP pose ``T_world_tcp`` (or ``T_base_tcp``): ``(4, 4)`` for one q, ``(N, 4, 4)`` for many."""
        Q, single = self.check_joints(q)
        V = self.check_values(values, Q.shape[0])
        if frame == "world":
            T = self.chain.evaluate(Q, V).T
        elif frame == "base":
            ev = self.chain.evaluate(Q, V, record_groups=True)
            T = _batch_inv(ev.group_frames["base"]) @ ev.T
        else:
            raise ValueError(f"frame must be 'world' or 'base', got {frame!r}")
        return T[0] if single else T

    def tool_points(self, q: ArrayLike, point_tcp: ArrayLike = (0.0, 0.0, 0.0), values=None) -> F64:
        """World position of a point given in the TCP frame: ``(3,)`` or ``(N, 3)``."""
        T = self.fk(q, values)
        p = np.asarray(point_tcp, dtype=float).reshape(3)
        return T[..., :3, :3] @ p + T[..., :3, 3]

    def jacobian(
        self,
        q: ArrayLike,
        values: ArrayLike | None = None,
        *,
        frame: JacobianFrame = "base",
        point_tcp: ArrayLike | None = None,
    ) -> F64:
        """Analytic Jacobian w.r.t. the joints, ``(6, n)`` or ``(N, 6, n)``; twist order ``(v, w)``."""
        Q, single = self.check_joints(q)
        V = self.check_values(values, Q.shape[0])
        pt = None if point_tcp is None else np.asarray(point_tcp, dtype=float).reshape(3)
        _, J = self.chain.screw_jacobian(Q, V, columns="joints", frame=frame, point_tcp=pt)
        return J[0] if single else J

    def fk_and_jacobian(self, q: ArrayLike, values=None, *, frame: JacobianFrame = "base"):
        """Both in one pass: ``(T, J)`` with the shapes of :meth:`fk` and :meth:`jacobian`."""
        Q, single = self.check_joints(q)
        V = self.check_values(values, Q.shape[0])
        T, J = self.chain.screw_jacobian(Q, V, columns="joints", frame=frame)
        return (T[0], J[0]) if single else (T, J)

    def param_jacobian(
        self,
        q: ArrayLike,
        values: ArrayLike | None = None,
        *,
        frame: JacobianFrame = "base",
        point_tcp: ArrayLike | None = None,
    ) -> tuple[F64, F64]:
        """``(T (N,4,4), J (N,6,P))``: derivative of the TCP pose w.r.t. every chain parameter."""
        Q, _ = self.check_joints(q)
        V = self.check_values(values, Q.shape[0])
        pt = None if point_tcp is None else np.asarray(point_tcp, dtype=float).reshape(3)
        return self.chain.screw_jacobian(Q, V, columns="params", frame=frame, point_tcp=pt)

    def link_frames(self, q: ArrayLike, values: ArrayLike | None = None) -> F64:
        """World pose of every link frame: ``(n, 4, 4)`` or ``(N, n, 4, 4)``."""
        Q, single = self.check_joints(q)
        V = self.check_values(values, Q.shape[0])
        g = self.chain.evaluate(Q, V, record_groups=True).group_frames
        F = np.stack([g[f"joint{j + 1}"] for j in range(self.dof)], axis=1)
        return F[0] if single else F

    # ----------------------------------------------------------------------------- statics

    def gravity_torque(
        self,
        q: ArrayLike,
        payload_kg: ArrayLike = 0.0,
        payload_com_tcp: ArrayLike = (0.0, 0.0, 0.0),
        values: ArrayLike | None = None,
    ) -> F64:
        """Torque (N m) that gravity applies about each joint axis: ``(n,)`` or ``(N, n)``.

        ``tau_j = w_j . sum_{k >= j} (c_k - o_j) x (m_k g)`` over the links downstream of joint *j*
        (and the payload at ``payload_com_tcp`` in the TCP frame); positive means gravity pulls the
        joint towards positive angles. Requires link masses in the model.
        """
        if self.links is None:
            raise ValueError(f"model {self.name!r} has no link masses (the 'links' section of its file)")
        Q, single = self.check_joints(q)
        V = self.check_values(values, Q.shape[0])
        m_load = np.broadcast_to(np.asarray(payload_kg, dtype=float), (Q.shape[0],))
        if not np.all(np.isfinite(m_load)) or np.any(m_load < 0):
            raise ValueError("payload_kg must be finite and >= 0")
        ev = self.chain.evaluate(Q, V, record_ops=True, record_groups=True)
        axes = ev.op_axis[:, list(self.chain.joint_param_index)]  # (N, n, 3)
        origins = ev.op_origin[:, list(self.chain.joint_param_index)]
        n = self.dof
        coms, forces = [], []
        for j, link in enumerate(self.links):
            F = ev.group_frames[f"joint{j + 1}"]
            coms.append(F[:, :3, :3] @ np.asarray(link.com_link) + F[:, :3, 3])
            forces.append(np.broadcast_to(link.mass_kg * self.gravity_world, coms[-1].shape))
        pc = np.asarray(payload_com_tcp, dtype=float).reshape(3)
        c_load = ev.T[:, :3, :3] @ pc + ev.T[:, :3, 3]
        f_load = m_load[:, None] * self.gravity_world
        # suffix sums over downstream links, payload included in every suffix
        moment = np.cross(c_load, f_load)
        force = f_load.copy()
        tau = np.empty((Q.shape[0], n))
        for j in range(n - 1, -1, -1):
            moment = moment + np.cross(coms[j], forces[j])
            force = force + forces[j]
            tau[:, j] = np.einsum("ij,ij->i", axes[:, j], moment - np.cross(origins[:, j], force))
        return tau[0] if single else tau

    # ----------------------------------------------------------------------------- frames

    @property
    def T_world_base(self) -> F64:
        """Robot base in the world, including the base error parameters."""
        return self.chain.evaluate(np.zeros((1, self.dof)), record_groups=True).group_frames["base"][0]

    @property
    def T_flange_tcp(self) -> F64:
        """TCP in the flange frame, including the tool error parameters."""
        g = self.chain.evaluate(np.zeros((1, self.dof)), record_groups=True).group_frames
        flange = g.get("flange", g[f"joint{self.dof}"])
        return inv(flange[0]) @ g["tool"][0]

    # ----------------------------------------------------------------------------- variants

    def _replace_chain(self, chain: KinematicChain, **kw) -> RobotModel:
        links = kw.pop("links", self.links)
        return RobotModel(
            kw.pop("name", self.name),
            kw.pop("convention", self.convention),
            chain,
            self.joints,
            links=links,
            gravity_world=self.gravity_world,
            description=self.description,
            sources=self.sources,
            home=self.home,
        )

    def with_values(self, values: ArrayLike) -> RobotModel:
        """Same robot with new chain parameter values (all of them, ``param_names`` order)."""
        return self._replace_chain(self.chain.with_values(values))

    def with_param_offsets(self, offsets: Mapping[str, float]) -> RobotModel:
        """Same robot with named parameters shifted, e.g. ``{"joint2.a": 1e-4, "base.tz": -2e-4}``."""
        v = self.param_values.copy()
        for k, dv in offsets.items():
            if not np.isfinite(dv):
                raise ValueError(f"offset of {k} is not finite")
            v[self.chain.index(k)] += dv
        return self.with_values(v)

    def _with_fixed(self, group: str, T: ArrayLike, name: str) -> RobotModel:
        M = as_transform(T, name=name)
        ops = [
            replace(op, matrix=M.copy()) if op.kind == "fixed" and op.group == group else op for op in self.chain.ops
        ]
        return self._replace_chain(KinematicChain(ops, self.param_values, self.dof))

    def with_tool(self, T_flange_tcp: ArrayLike) -> RobotModel:
        """Same robot with another nominal tool (flange -> TCP); rejects non-rigid transforms."""
        return self._with_fixed("tool", T_flange_tcp, "T_flange_tcp")

    def with_base(self, T_world_base: ArrayLike) -> RobotModel:
        """Same robot mounted elsewhere (world -> base); rejects non-rigid transforms."""
        return self._with_fixed("base", T_world_base, "T_world_base")

    def with_links(self, links: Sequence[LinkInertia] | None) -> RobotModel:
        return self._replace_chain(self.chain, links=links)

    # ----------------------------------------------------------------------------- conversions

    def dh_rows(self) -> list[DHRow]:
        """The current DH / MDH table (errors included) of a ``dh`` or ``mdh`` model."""
        if self.convention not in ("dh", "mdh"):
            raise ValueError(f"{self.name} is a {self.convention} model; it has no DH table")
        v = dict(zip(self.param_names, self.param_values, strict=True))
        keys = ("a", "alpha", "d", "theta", "beta")
        return [DHRow(**{k: float(v[f"joint{j + 1}.{k}"]) for k in keys}) for j in range(self.dof)]

    def _fixed_matrix(self, group: str) -> F64:
        for op in self.chain.ops:
            if op.kind == "fixed" and op.group == group:
                return op.matrix
        return np.eye(4)

    def _group_errors(self, group: str) -> dict[str, float]:
        return {
            n: float(v) for n, v in zip(self.param_names, self.param_values, strict=True) if n.startswith(group + ".")
        }

    def _converted(self, convention: str, joints, **chain_kw) -> RobotModel:
        """A converted model with base/tool errors carried over and link COMs re-expressed."""
        chain = build_chain(
            convention,  # type: ignore[arg-type]
            joints,
            T_flange_tcp=self._fixed_matrix("tool"),
            **chain_kw,
        )
        errors = self._group_errors("base") | self._group_errors("tool")
        vals = chain.values.copy()
        for k, v in errors.items():
            vals[chain.index(k)] = v
        out = self._replace_chain(chain.with_values(vals), convention=convention, links=None)
        if self.links is not None:
            zero = np.zeros(self.dof)
            F_old, F_new = self.link_frames(zero), out.link_frames(zero)
            links = []
            for j, link in enumerate(self.links):
                c = (inv(F_new[j]) @ F_old[j] @ np.append(link.com_link, 1.0))[:3]
                links.append(LinkInertia(link.mass_kg, (float(c[0]), float(c[1]), float(c[2]))))
            out = out.with_links(links)
        return out

    def poe_screws_at_zero(self) -> tuple[list[PoeJoint], F64]:
        """Joint axes/points and the flange pose at q = 0 in the base frame (errors included)."""
        zero = np.zeros((1, self.dof))
        ev = self.chain.evaluate(zero, record_ops=True, record_groups=True)
        idx = list(self.chain.joint_param_index)
        axes, points = ev.op_axis[0, idx], ev.op_origin[0, idx]
        T_bw = inv(ev.group_frames["base"][0])
        flange = ev.group_frames.get("flange", ev.group_frames[f"joint{self.dof}"])[0]
        joints = [
            PoeJoint(tuple((T_bw[:3, :3] @ a).tolist()), tuple((T_bw[:3, :3] @ p + T_bw[:3, 3]).tolist()))
            for a, p in zip(axes, points, strict=True)
        ]
        return joints, T_bw @ flange

    def to_convention(self, convention: str) -> RobotModel:
        """The same robot (same FK for every q) in another parameterisation.

        dh <-> mdh are exact rewrites of the table (the constant left over goes to the base or the
        flange group); any -> poe takes the joint screws at q = 0. poe -> dh/mdh is not provided.
        """
        if convention == self.convention:
            return self
        if convention == "poe":
            joints, M = self.poe_screws_at_zero()
            return self._converted("poe", joints, T_world_base=self._fixed_matrix("base"), M_flange_at_zero=M)
        if self.convention == "dh" and convention == "mdh":
            rows, T_extra = dh_to_mdh(self.dh_rows())
            return self._converted(
                "mdh",
                rows,
                T_world_base=self._fixed_matrix("base"),
                T_last_flange=T_extra @ self._fixed_matrix("flange"),
            )
        if self.convention == "mdh" and convention == "dh":
            if any(v != 0.0 for v in self._group_errors("base").values()):
                raise ValueError("mdh -> dh with non-zero base errors is not supported: fold them first")
            rows, T_prefix = mdh_to_dh(self.dh_rows())
            return self._converted(
                "dh",
                rows,
                T_world_base=self._fixed_matrix("base") @ T_prefix,
                T_last_flange=self._fixed_matrix("flange"),
            )
        raise ValueError(f"conversion {self.convention} -> {convention} is not supported")

    # ----------------------------------------------------------------------------- IK

    def ik(self, T_world_tcp: ArrayLike, q_seed: ArrayLike | None = None, **kwargs) -> IKResult:
        """Numerical IK within the joint limits; see :func:`plugins.robot.ik.solve_ik`."""
        return solve_ik(self, T_world_tcp, q_seed, **kwargs)


def _batch_inv(T: F64) -> F64:
    out = np.zeros_like(T)
    R_T = np.swapaxes(T[:, :3, :3], 1, 2)
    out[:, :3, :3] = R_T
    out[:, :3, 3] = -(R_T @ T[:, :3, 3:4])[:, :, 0]
    out[:, 3, 3] = 1.0
    return out


__all__ = ["ChainOp", "JointSpec", "LinkInertia", "RobotModel"]
