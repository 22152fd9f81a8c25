"""The kinematic-chain engine: a serial robot as a product of elementary transforms, vectorised.

Every supported parameterisation (standard DH, modified DH, POE, base and tool frames) compiles to
one list of *elementary operations* applied left to right::

    T_world_tcp(q) = E_1 E_2 ... E_K,   E_k in {Rx, Ry, Rz, Tx, Ty, Tz}(value_k [+ q_j])  or a fixed 4x4

Each scalar operation has a unique name (``joint2.a``, ``base.tz``, ``tool.rx`` ...) and a value; a
revolute joint is an ``rz`` operation whose value (the joint's zero offset, ``jointN.theta``) is
added to the joint angle. Keeping one named value per elementary motion is what lets kinematic
calibration and the model-gap workflow perturb *any* geometric parameter, per
sample if they need to (thermal drift), and get its analytic Jacobian for free:
the derivative of the chain with respect to an elementary motion is the unit screw of that motion,
expressed in the world frame where the operation happens.

Evaluation works on the columns of the running frame (x, y, z axes and origin, each ``(3, N)``), so
a rotation or translation costs a handful of vector operations and no 4x4 matrix products: this is
what makes forward kinematics cheap for tens of thousands of configurations at once.

Jacobian conventions (twist order ``(v, w)`` as in :mod:`engine.transforms`):

``frame="space"``  spatial twist: ``T(q + dq) ~= exp_se3(J dq) @ T(q)`` (left perturbation, the
                   convention of ``engine.transforms``).
``frame="base"``   geometric Jacobian in world coordinates: ``v`` is the velocity of the TCP origin
                   (or of the given point), ``w`` the angular velocity.
``frame="tool"``   body twist: ``T(q + dq) ~= T(q) @ exp_se3(J dq)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.transforms import as_transform

F64 = NDArray[np.float64]
OpKind = Literal["rx", "ry", "rz", "tx", "ty", "tz", "fixed"]
JacobianFrame = Literal["space", "base", "tool"]

SCALAR_KINDS = ("rx", "ry", "rz", "tx", "ty", "tz")
_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}
#: rotation about a local axis: (fixed column, a, b) with a' = c a + s b, b' = -s a + c b
_ROT_COLUMNS = {"rx": (0, 1, 2), "ry": (1, 2, 0), "rz": (2, 0, 1)}


@dataclass(frozen=True)
class ChainOp:
    """One elementary operation of the chain.

    ``kind`` is a rotation (``rx ry rz``) or translation (``tx ty tz``) along an axis of the current
    frame, or ``fixed`` (a constant rigid 4x4 in ``matrix``). Scalar operations carry a unique
    ``name``; ``joint`` (0-based) marks the operation the joint variable is added to. ``group``
    names the part of the robot the operation belongs to (``base``, ``joint1`` ... ``jointN``,
    ``flange``, ``tool``); the frame at the end of group ``jointN`` is link N's frame.
    """

    kind: OpKind
    group: str
    name: str | None = None
    joint: int | None = None
    matrix: F64 | None = None

    @property
    def is_rotation(self) -> bool:
        return self.kind in ("rx", "ry", "rz")

    @property
    def axis(self) -> int:
        return _AXIS_INDEX[self.kind[1]]


@dataclass
class ChainEvaluation:
    """Result of one vectorised pass over the chain (N configurations).

    ``T`` is ``(N, 4, 4)``. When recorded, ``op_axis`` / ``op_origin`` are ``(N, P, 3)``: the world
    direction and the origin of every scalar operation (in parameter order), and ``group_frames``
    maps a group name to its end frame ``(N, 4, 4)``.
    """

    T: F64
    op_axis: F64 | None = None
    op_origin: F64 | None = None
    group_frames: dict[str, F64] | None = None


class KinematicChain:
    """A serial chain of elementary operations with named scalar values (see module docstring)."""

    def __init__(self, ops: Sequence[ChainOp], values: ArrayLike, n_joints: int) -> None:
        self.ops: tuple[ChainOp, ...] = tuple(ops)
        self.n_joints = int(n_joints)
        names: list[str] = []
        self._scalar_index: list[int] = []  # op index -> parameter index (or -1)
        for op in self.ops:
            if op.kind == "fixed":
                if op.matrix is None:
                    raise ValueError(f"fixed operation in group {op.group!r} has no matrix")
                as_transform(op.matrix, name=f"fixed transform in group {op.group!r}")
                if op.name is not None or op.joint is not None:
                    raise ValueError("a fixed operation takes neither a name nor a joint")
                self._scalar_index.append(-1)
                continue
            if op.kind not in SCALAR_KINDS:
                raise ValueError(f"unknown chain operation kind {op.kind!r}")
            if not op.name:
                raise ValueError(f"scalar operation {op.kind} in group {op.group!r} needs a name")
            if op.name in names:
                raise ValueError(f"duplicate chain parameter name {op.name!r}")
            if op.joint is not None and not op.is_rotation:
                raise ValueError(f"{op.name}: only revolute joints are supported")
            self._scalar_index.append(len(names))
            names.append(op.name)
        joint_ops = [op.joint for op in self.ops if op.joint is not None]
        if sorted(joint_ops) != list(range(self.n_joints)):
            raise ValueError(f"the chain must drive each of its {self.n_joints} joints exactly once")
        self.param_names: tuple[str, ...] = tuple(names)
        self._name_to_index = {n: i for i, n in enumerate(names)}
        v = np.asarray(values, dtype=float).reshape(-1)
        if v.shape != (len(names),):
            raise ValueError(f"chain has {len(names)} parameters, got {v.shape[0]} values")
        if not np.all(np.isfinite(v)):
            raise ValueError("chain parameter values contain NaN or infinity")
        self.values: F64 = v
        self.values.setflags(write=False)
        self.joint_param_index: tuple[int, ...] = tuple(
            self._scalar_index[k] for j in range(self.n_joints) for k, op in enumerate(self.ops) if op.joint == j
        )
        self._compiled: tuple[bytes, list[F64], list[tuple[int, int, str]]] | None = None
        self._param_is_rotation = np.array([op.is_rotation for op in self.ops if op.kind != "fixed"])
        self.groups: tuple[str, ...] = tuple(dict.fromkeys(op.group for op in self.ops))

    # ----------------------------------------------------------------------------- parameters

    def index(self, name: str) -> int:
        """Position of a named parameter in the value vector (KeyError with the close names)."""
        try:
            return self._name_to_index[name]
        except KeyError:
            from difflib import get_close_matches

            close = get_close_matches(name, self.param_names, n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise KeyError(f"no chain parameter {name!r}{hint}") from None

    def param_kind(self, name: str) -> str:
        """``"length"`` (metres) or ``"angle"`` (radians) for a named parameter."""
        op = self.ops[self._scalar_index.index(self.index(name))]
        return "angle" if op.is_rotation else "length"

    def with_values(self, values: ArrayLike) -> KinematicChain:
        """Same structure, new nominal values."""
        return KinematicChain(self.ops, values, self.n_joints)

    def reach_bound(self, values: F64 | None = None, skip_groups: Sequence[str] = ()) -> float:
        """Sum of all translation lengths (an upper bound of how far the chain's end can get)."""
        v = self.values if values is None else values
        total = 0.0
        for op, i in zip(self.ops, self._scalar_index, strict=True):
            if op.group in skip_groups:
                continue
            if op.kind == "fixed":
                total += float(np.linalg.norm(op.matrix[:3, 3]))
            elif not op.is_rotation:
                total += abs(float(v[i]))
        return total

    # ----------------------------------------------------------------------------- evaluation

    def evaluate(
        self,
        q: F64,
        values: F64 | None = None,
        *,
        record_ops: bool = False,
        record_groups: bool = False,
    ) -> ChainEvaluation:
        """Forward kinematics for ``q`` of shape ``(N, n_joints)``.

        ``values`` are the chain parameters: ``None`` for the nominal ones, ``(P,)`` for one set
        shared by all samples, or ``(N, P)`` for one set per sample. Inputs are assumed validated
        (the robot model does that).
        """
        n = q.shape[0]
        per_sample = values is not None and values.ndim == 2
        if not (per_sample or record_ops or record_groups):
            return ChainEvaluation(T=self._evaluate_compiled(q, self.values if values is None else values)[0])
        vals = self.values if values is None else values
        cols = [np.zeros((3, n)) for _ in range(4)]
        cols[0][0] = 1.0
        cols[1][1] = 1.0
        cols[2][2] = 1.0
        P = len(self.param_names)
        op_axis = np.empty((P, 3, n)) if record_ops else None
        op_origin = np.empty((P, 3, n)) if record_ops else None
        groups: dict[str, F64] = {}
        for k, op in enumerate(self.ops):
            if op.kind == "fixed":
                C = op.matrix
                x, y, z, p = cols
                new = [C[0, j] * x + C[1, j] * y + C[2, j] * z for j in range(3)]
                new.append(p + C[0, 3] * x + C[1, 3] * y + C[2, 3] * z)
                cols = new
            else:
                i = self._scalar_index[k]
                v = vals[:, i] if per_sample else vals[i]
                if op.joint is not None:
                    v = v + q[:, op.joint]
                if op.is_rotation:
                    _, a, b = _ROT_COLUMNS[op.kind]
                    if np.ndim(v) or v != 0.0:
                        c, s = np.cos(v), np.sin(v)
                        ca, cb = cols[a], cols[b]
                        cols[a], cols[b] = c * ca + s * cb, c * cb - s * ca
                elif np.ndim(v) or v != 0.0:
                    cols[3] = cols[3] + v * cols[op.axis]
                if record_ops:
                    op_axis[i] = cols[op.axis]
                    op_origin[i] = cols[3]
            if record_groups and (k + 1 == len(self.ops) or self.ops[k + 1].group != op.group):
                groups[op.group] = _assemble(cols)
        ev = ChainEvaluation(T=_assemble(cols))
        if record_ops:
            ev.op_axis = np.moveaxis(op_axis, 2, 0)
            ev.op_origin = np.moveaxis(op_origin, 2, 0)
        if record_groups:
            ev.group_frames = groups
        return ev

    def _compile(self, v: F64) -> tuple[list[F64], list[tuple[int, int, str]]]:
        """Fold every run of non-joint operations into one constant 4x4 (cached per value vector).

        Returns the constant segments ``C_0 .. C_n`` and, per joint operation in chain order,
        ``(joint index, parameter index of its offset, kind)``: ``T = C_0 R_1(q) C_1 ... R_n(q) C_n``.
        """
        key = v.tobytes()
        if self._compiled is not None and self._compiled[0] == key:
            return self._compiled[1], self._compiled[2]
        segments: list[F64] = []
        joints: list[tuple[int, int, str]] = []
        M = np.eye(4)
        for k, op in enumerate(self.ops):
            if op.kind == "fixed":
                M = M @ op.matrix
            elif op.joint is not None:
                segments.append(M)
                joints.append((op.joint, self._scalar_index[k], op.kind))
                M = np.eye(4)
            else:
                M = M @ _elementary(op.kind, float(v[self._scalar_index[k]]))
        segments.append(M)
        segments = [segments[0]] + [None if _is_identity(C) else C for C in segments[1:]]
        self._compiled = (key, segments, joints)
        return segments, joints

    def _evaluate_compiled(self, q: F64, v: F64, record_joints: bool = False) -> tuple[F64, F64 | None, F64 | None]:
        """Fast FK for parameters shared by all samples; optionally the joint axes and origins.

        The running frame is a ``(4, 3, N)`` stack of its columns (x, y, z axes and origin), so a
        constant segment is one ``C^T @ X`` product and a joint rotation updates two columns.
        """
        segments, joints = self._compile(v)
        n = q.shape[0]
        X = np.repeat(segments[0][:3, :].T[:, :, None], n, axis=2)  # rows: columns of C_0
        axes = np.empty((n, self.n_joints, 3)) if record_joints else None
        origins = np.empty((n, self.n_joints, 3)) if record_joints else None
        for (j, i, kind), C in zip(joints, segments[1:], strict=True):
            _, a, b = _ROT_COLUMNS[kind]
            ang = v[i] + q[:, j]
            c, s = np.cos(ang), np.sin(ang)
            Xa, Xb = X[a], X[b]
            X[a], X[b] = c * Xa + s * Xb, c * Xb - s * Xa
            if record_joints:
                axes[:, j] = X[_AXIS_INDEX[kind[1]]].T
                origins[:, j] = X[3].T
            if C is not None:
                X = (C.T @ X.reshape(4, -1)).reshape(4, 3, n)
        T = np.zeros((n, 4, 4))
        T[:, :3, :] = X.transpose(2, 1, 0)
        T[:, 3, 3] = 1.0
        return T, axes, origins

    # ----------------------------------------------------------------------------- Jacobians

    def screw_jacobian(
        self,
        q: F64,
        values: F64 | None = None,
        *,
        columns: Literal["joints", "params"] = "joints",
        frame: JacobianFrame = "base",
        point_tcp: F64 | None = None,
    ) -> tuple[F64, F64]:
        """``(T, J)``: the end transform ``(N, 4, 4)`` and a ``(N, 6, m)`` Jacobian.

        ``columns="joints"`` differentiates with respect to the joint angles (m = n_joints);
        ``columns="params"`` with respect to every chain parameter (m = P, in ``param_names``
        order). ``point_tcp`` (3,) moves the reference point of ``frame="base"`` from the TCP origin
        to that point of the TCP frame (used for position-only measurements of a tool point).
        """
        if columns == "joints" and (values is None or values.ndim == 1):
            T, axis, origin = self._evaluate_compiled(q, self.values if values is None else values, True)
            idx = list(self.joint_param_index)
        else:
            ev = self.evaluate(q, values, record_ops=True)
            T = ev.T
            idx = list(self.joint_param_index) if columns == "joints" else slice(None)
            axis = ev.op_axis[:, idx]  # (N, m, 3)
            origin = ev.op_origin[:, idx]
        rot = self._param_is_rotation[idx][None, :, None]
        n, m = axis.shape[0], axis.shape[1]
        J = np.zeros((n, 6, m))
        if frame == "base":
            p_e = T[:, :3, 3] if point_tcp is None else T[:, :3, :3] @ point_tcp + T[:, :3, 3]
            lever = p_e[:, None, :] - origin
            v = np.where(rot, np.cross(axis, lever), axis)
        else:
            v = np.where(rot, np.cross(origin, axis), axis)
        J[:, :3, :] = np.swapaxes(v, 1, 2)
        J[:, 3:, :] = np.swapaxes(np.where(rot, axis, 0.0), 1, 2)
        if frame == "tool":  # body twist = Ad(T^-1) spatial twist: v_b = R^T (v_s + w_s x t), w_b = R^T w_s
            R_T = np.swapaxes(T[:, :3, :3], 1, 2)
            w_s = J[:, 3:, :]
            v_s = J[:, :3, :] + np.cross(w_s, T[:, :3, 3][:, :, None], axis=1)
            J = np.concatenate([R_T @ v_s, R_T @ w_s], axis=1)
        return T, J


def _is_identity(C: F64) -> bool:
    return bool(np.array_equal(C, _EYE4))


_EYE4 = np.eye(4)


def _elementary(kind: str, v: float) -> F64:
    """4x4 of one elementary rotation or translation."""
    E = np.eye(4)
    if kind[0] == "t":
        E[_AXIS_INDEX[kind[1]], 3] = v
        return E
    _, a, b = _ROT_COLUMNS[kind]
    c, s = np.cos(v), np.sin(v)
    E[a, a], E[b, a], E[a, b], E[b, b] = c, s, -s, c
    return E


def _assemble(cols: list[F64]) -> F64:
    n = cols[0].shape[1]
    T = np.zeros((n, 4, 4))
    for j in range(4):
        T[:, :3, j] = cols[j].T
    T[:, 3, 3] = 1.0
    return T
