"""Robot parameterisations (standard DH, modified DH, POE) compiled into a :class:`KinematicChain`.

Conventions (all revolute joints, metres and radians):

``dh`` (standard / distal DH)   ``A_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i) Ry(beta_i)``
``mdh`` (modified / Craig)      ``A_i = Rx(alpha_{i-1}) Tx(a_{i-1}) Ry(beta_{i-1}) Rz(theta_i + q_i) Tz(d_i)``
                                (MDH row *i* holds ``alpha_{i-1}, a_{i-1}, beta_{i-1}, theta_i, d_i``)
``poe`` (product of exponentials, space form)
                                ``T(q) = exp([S_1] q_1) ... exp([S_n] q_n) M`` with each screw given by
                                its unit axis ``w_i`` and a point ``p_i`` on it at the zero configuration
                                (``S_i = (p_i x w_i, w_i)`` in the ``(v, w)`` order of engine.transforms).

``beta`` is Hayati's extra rotation (default 0) that models a small misalignment of nominally
parallel axes, which plain DH cannot represent; it lets the DH-error effect and the kinematic
calibration describe real parallel-axis errors.

POE compiles to ``G_1 Rz(q_1) G_1^-1 G_2 Rz(q_2) ... G_n^-1 M`` where ``G_i`` is a frame on axis *i*
with its z along the axis (``exp([S_i] q) = G_i Rz(q) G_i^-1``); each joint group also carries five
zero-valued error operations ``jointN.tx ty tz rx ry`` on ``G_i`` (a local-POE error model) so that a
POE-parameterised robot can be calibrated or perturbed like a DH one.

The whole model chain is: ``base`` group (``T_world_base`` then errors ``base.tx .. base.rz`` in the
base frame), the joint groups, a ``flange`` group (fixed transform from the last joint frame to the
mechanical flange), and the ``tool`` group (``tool.tx ty tz`` in the flange frame, ``T_flange_tcp``,
``tool.rx ry rz`` about the TCP axes).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.transforms import T_from_Rt, as_transform, inv
from plugins.robot.chain import ChainOp, KinematicChain

F64 = NDArray[np.float64]
Convention = Literal["dh", "mdh", "poe"]
CONVENTIONS: tuple[str, ...] = ("dh", "mdh", "poe")


@dataclass(frozen=True)
class DHRow:
    """One row of a DH or MDH table (metres, radians). See the module docstring for the meaning."""

    a: float
    alpha: float
    d: float
    theta: float = 0.0
    beta: float = 0.0


@dataclass(frozen=True)
class PoeJoint:
    """A revolute joint of a POE model: unit axis and a point on it, in the base frame at q = 0."""

    axis: tuple[float, float, float]
    point: tuple[float, float, float]


def _is_identity(T: F64) -> bool:
    return bool(np.allclose(T, np.eye(4), atol=1e-15, rtol=0.0))


def _fixed(T: ArrayLike, group: str, keep_identity: bool = False) -> list[ChainOp]:
    M = as_transform(T, name=f"{group} transform")
    return [] if _is_identity(M) and not keep_identity else [ChainOp("fixed", group, matrix=M.copy())]


def _scalar(kind: str, group: str, name: str, value: float, ops: list, vals: list, joint=None) -> None:
    ops.append(ChainOp(kind, group, name=name, joint=joint))  # type: ignore[arg-type]
    vals.append(float(value))


def base_group(T_world_base: ArrayLike) -> tuple[list[ChainOp], list[float]]:
    """``T_world_base`` followed by six zero-valued error operations in the base frame."""
    ops, vals = _fixed(T_world_base, "base", keep_identity=True), []
    for kind in ("tx", "ty", "tz", "rx", "ry", "rz"):
        _scalar(kind, "base", f"base.{kind}", 0.0, ops, vals)
    return ops, vals


def tool_group(T_flange_tcp: ArrayLike) -> tuple[list[ChainOp], list[float]]:
    """Position errors in the flange frame, ``T_flange_tcp``, rotation errors about the TCP axes."""
    ops: list[ChainOp] = []
    vals: list[float] = []
    for kind in ("tx", "ty", "tz"):
        _scalar(kind, "tool", f"tool.{kind}", 0.0, ops, vals)
    ops += _fixed(T_flange_tcp, "tool", keep_identity=True)
    for kind in ("rx", "ry", "rz"):
        _scalar(kind, "tool", f"tool.{kind}", 0.0, ops, vals)
    return ops, vals


def dh_joint_groups(rows: Sequence[DHRow], modified: bool) -> tuple[list[ChainOp], list[float]]:
    """Operations of all joints of a DH (``modified=False``) or MDH table."""
    ops: list[ChainOp] = []
    vals: list[float] = []
    for j, r in enumerate(rows):
        g = f"joint{j + 1}"
        if modified:
            _scalar("rx", g, f"{g}.alpha", r.alpha, ops, vals)
            _scalar("tx", g, f"{g}.a", r.a, ops, vals)
            _scalar("ry", g, f"{g}.beta", r.beta, ops, vals)
            _scalar("rz", g, f"{g}.theta", r.theta, ops, vals, joint=j)
            _scalar("tz", g, f"{g}.d", r.d, ops, vals)
        else:
            _scalar("rz", g, f"{g}.theta", r.theta, ops, vals, joint=j)
            _scalar("tz", g, f"{g}.d", r.d, ops, vals)
            _scalar("tx", g, f"{g}.a", r.a, ops, vals)
            _scalar("rx", g, f"{g}.alpha", r.alpha, ops, vals)
            _scalar("ry", g, f"{g}.beta", r.beta, ops, vals)
    return ops, vals


def frame_on_axis(axis: ArrayLike, point: ArrayLike) -> F64:
    """A frame with origin ``point`` and z along the unit ``axis`` (x chosen deterministically)."""
    w = np.asarray(axis, dtype=float).reshape(3)
    nw = np.linalg.norm(w)
    if not np.isfinite(nw) or abs(nw - 1.0) > 1e-6:
        raise ValueError(f"POE joint axis must be a unit vector, got {w} (norm {nw:.6g})")
    w = w / nw
    helper = np.eye(3)[int(np.argmin(np.abs(w)))]
    x = np.cross(helper, w)
    x /= np.linalg.norm(x)
    return T_from_Rt(np.column_stack([x, np.cross(w, x), w]), np.asarray(point, dtype=float).reshape(3))


def poe_joint_groups(joints: Sequence[PoeJoint]) -> tuple[list[ChainOp], list[float], F64]:
    """Operations of all joints of a POE model and ``G_n`` (the last joint frame at q = 0)."""
    ops: list[ChainOp] = []
    vals: list[float] = []
    G_prev = np.eye(4)
    for j, jt in enumerate(joints):
        g = f"joint{j + 1}"
        G = frame_on_axis(jt.axis, jt.point)
        ops += _fixed(inv(G_prev) @ G, g)
        for kind in ("tx", "ty", "tz", "rx", "ry"):
            _scalar(kind, g, f"{g}.{kind}", 0.0, ops, vals)
        _scalar("rz", g, f"{g}.theta", 0.0, ops, vals, joint=j)
        G_prev = G
    return ops, vals, G_prev


def build_chain(
    convention: Convention,
    joints: Sequence[DHRow] | Sequence[PoeJoint],
    *,
    T_world_base: ArrayLike | None = None,
    T_flange_tcp: ArrayLike | None = None,
    T_last_flange: ArrayLike | None = None,
    M_flange_at_zero: ArrayLike | None = None,
) -> KinematicChain:
    """Compile a robot into a :class:`KinematicChain` (groups base, joints, flange, tool).

    For ``dh``/``mdh`` the flange is the last joint frame times ``T_last_flange`` (default
    identity). For ``poe`` the flange pose at q = 0 is ``M_flange_at_zero`` (required).
    """
    if convention not in CONVENTIONS:
        raise ValueError(f"unknown convention {convention!r}; use one of {', '.join(CONVENTIONS)}")
    if len(joints) == 0:
        raise ValueError("a robot needs at least one joint")
    ops, vals = base_group(np.eye(4) if T_world_base is None else T_world_base)
    if convention == "poe":
        if not all(isinstance(j, PoeJoint) for j in joints):
            raise TypeError("a poe chain takes PoeJoint entries")
        if M_flange_at_zero is None:
            raise ValueError("a poe chain needs the flange pose at the zero configuration (M)")
        jops, jvals, G_n = poe_joint_groups(joints)  # type: ignore[arg-type]
        flange = inv(G_n) @ as_transform(M_flange_at_zero, name="flange pose at zero (M)")
    else:
        if not all(isinstance(j, DHRow) for j in joints):
            raise TypeError(f"a {convention} chain takes DHRow entries")
        jops, jvals = dh_joint_groups(joints, modified=convention == "mdh")  # type: ignore[arg-type]
        flange = np.eye(4) if T_last_flange is None else as_transform(T_last_flange, name="T_last_flange")
    ops += jops
    vals += jvals
    ops += _fixed(flange, "flange")
    tops, tvals = tool_group(np.eye(4) if T_flange_tcp is None else T_flange_tcp)
    return KinematicChain(ops + tops, vals + tvals, n_joints=len(joints))


# --------------------------------------------------------------------------- conversions


def dh_to_mdh(rows: Sequence[DHRow]) -> tuple[list[DHRow], F64]:
    """Exact DH -> MDH rewrite: ``(mdh_rows, T_extra)`` with flange_dh = flange_mdh @ T_extra.

    The DH product ``[Rz Tz][Tx Rx Ry Rz Tz]...[Tx Rx Ry]`` regroups into MDH rows whose
    ``alpha, a, beta`` are the previous DH row's, plus ``Tx(a_n) Rx(alpha_n) Ry(beta_n)`` at the end.
    """
    out: list[DHRow] = []
    prev = DHRow(0.0, 0.0, 0.0)
    for r in rows:
        out.append(DHRow(a=prev.a, alpha=prev.alpha, d=r.d, theta=r.theta, beta=prev.beta))
        prev = r
    return out, _tx_rx_ry(prev.a, prev.alpha, prev.beta)


def mdh_to_dh(rows: Sequence[DHRow]) -> tuple[list[DHRow], F64]:
    """Exact MDH -> DH rewrite: ``(dh_rows, T_prefix)`` with ``T = T_prefix @ DH chain``.

    ``T_prefix = Rx(alpha_0) Tx(a_0) Ry(beta_0)`` belongs in front of the first joint (the base).
    """
    out: list[DHRow] = []
    for i, r in enumerate(rows):
        nxt = rows[i + 1] if i + 1 < len(rows) else DHRow(0.0, 0.0, 0.0)
        out.append(DHRow(a=nxt.a, alpha=nxt.alpha, d=r.d, theta=r.theta, beta=nxt.beta))
    return out, _tx_rx_ry(rows[0].a, rows[0].alpha, rows[0].beta)


def _tx_rx_ry(a: float, alpha: float, beta: float) -> F64:
    ca, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
    Rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    Ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    return T_from_Rt(Rx @ Ry, (a, 0.0, 0.0))
