"""Numerical inverse kinematics with joint limits (scipy ``least_squares``), multiple seeds.

The residual is ``[p(q) - p_target, L * log(R(q) R_target^T)]`` in the world frame (``L``,
``rotation_weight_m``, converts radians to metres so both parts weigh alike), with the analytic
Jacobian from :meth:`RobotModel.jacobian`. The solver first tries the caller's seed (so a
nearby solution keeps the arm on its current branch), then deterministic random seeds.

A failure says why (``status``):

``unreachable``     no configuration reaches the target, even ignoring the joint limits;
``out_of_limits``   a configuration reaches it, but only outside the joint limits (listed in
                    ``reason``; ``q`` holds that configuration for diagnosis, ``success`` is False).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from engine.transforms import as_transform, hat, log_so3
from plugins.robot.chain import JacobianFrame, KinematicChain

F64 = NDArray[np.float64]
IKStatus = Literal["ok", "unreachable", "out_of_limits"]


class ArmModel(Protocol):
    """What the solver uses of a plugins.robot.kinematics.RobotModel (whose ``ik`` method calls
    :func:`solve_ik`), named here so that this module does not import the model that imports it."""

    chain: KinematicChain
    home: F64
    lower: F64
    upper: F64

    @property
    def dof(self) -> int: ...

    def check_joints(self, q: ArrayLike, *, name: str = "q") -> tuple[F64, bool]: ...

    def check_values(self, values: ArrayLike | None, n: int) -> F64 | None: ...

    def within_limits(self, q: ArrayLike, margin: float = 0.0) -> Any: ...

    def limit_violations(self, q: ArrayLike) -> list[str]: ...

    def fk(
        self, q: ArrayLike, values: ArrayLike | None = None, *, frame: Literal["world", "base"] = "world"
    ) -> F64: ...

    def fk_and_jacobian(self, q: ArrayLike, values: Any = None, *, frame: JacobianFrame = "base") -> Any: ...


@dataclass(frozen=True)
class IKResult:
    """Outcome of :func:`solve_ik`. ``q`` is within the limits whenever ``success`` is True."""

    success: bool
    status: IKStatus
    q: F64 | None
    reason: str
    position_error_m: float
    rotation_error_rad: float
    attempts: int


def so3_left_jacobian_inv(phi: F64) -> F64:
    """``J_l(phi)^-1``: maps an angular velocity to the rate of the rotation vector ``phi``."""
    th = float(np.linalg.norm(phi))
    P = hat(phi)
    if th < 1e-6:
        return np.eye(3) - 0.5 * P + P @ P / 12.0
    coef = 1.0 / th**2 - (1.0 + np.cos(th)) / (2.0 * th * np.sin(th))
    return np.eye(3) - 0.5 * P + coef * (P @ P)


class _Problem:
    def __init__(self, model: ArmModel, T_target: F64, values, position_only: bool, weight: float):
        self.model = model
        self.p_t = T_target[:3, 3]
        self.R_t = T_target[:3, :3]
        self.values = values
        self.position_only = position_only
        self.w = weight

    def errors(self, q: F64) -> tuple[float, float]:
        T = self.model.fk(q, self.values)
        return float(np.linalg.norm(T[:3, 3] - self.p_t)), float(np.linalg.norm(log_so3(T[:3, :3] @ self.R_t.T)))

    def residual_and_jacobian(self, q: F64) -> tuple[F64, F64]:
        T, J = self.model.fk_and_jacobian(q, self.values, frame="base")
        r_p = T[:3, 3] - self.p_t
        if self.position_only:
            return r_p, J[:3]
        phi = log_so3(T[:3, :3] @ self.R_t.T)
        Jr = so3_left_jacobian_inv(phi) @ J[3:] if np.linalg.norm(phi) < 3.0 else J[3:]
        return np.concatenate([r_p, self.w * phi]), np.vstack([J[:3], self.w * Jr])

    def solve(self, q0: F64, bounds, max_nfev: int) -> F64:
        cache: dict[bytes, tuple[F64, F64]] = {}

        def rj(q):
            key = q.tobytes()
            if key not in cache:
                cache.clear()
                cache[key] = self.residual_and_jacobian(q)
            return cache[key]

        method = "trf" if bounds is not None else "lm"
        kw = {"bounds": bounds} if bounds is not None else {}
        sol = least_squares(
            lambda q: rj(q)[0],
            q0,
            jac=lambda q: rj(q)[1],
            method=method,
            xtol=1e-14,
            ftol=1e-14,
            gtol=1e-14,
            max_nfev=max_nfev,
            **kw,
        )
        return sol.x


def _wrap_into_limits(q: F64, lower: F64, upper: F64, seed: F64) -> F64:
    """Shift joints by multiples of 2 pi towards the limits (and the seed) where that helps."""
    out = q.copy()
    for j in range(q.size):
        ks = np.arange(-3, 4)
        cand = q[j] + 2 * np.pi * ks
        ok = cand[(cand >= lower[j]) & (cand <= upper[j])]
        if ok.size:
            out[j] = ok[np.argmin(np.abs(ok - seed[j]))]
    return out


def _reach_bound(model: ArmModel, values: F64 | None) -> tuple[F64, float]:
    """(base origin in the world, upper bound of the TCP's distance from it)."""
    v = None if values is None else values.reshape(-1)
    ev = model.chain.evaluate(np.zeros((1, model.dof)), v, record_groups=True)
    return ev.group_frames["base"][0, :3, 3], model.chain.reach_bound(v, skip_groups=("base",))


def _seeds(model: ArmModel, seed: F64, n_random_seeds: int, rng_seed: int) -> list[F64]:
    """The start points, in the order tried: the caller's seed clipped just inside the limits, then
    ``n_random_seeds`` uniform random ones drawn with ``rng_seed``."""
    lo, hi = model.lower, model.upper
    span = hi - lo
    eps = 1e-9 * span
    rng = np.random.default_rng(rng_seed)
    seeds = [np.clip(seed, lo + eps, hi - eps)]
    seeds += [lo + eps + rng.random(model.dof) * (span - 2 * eps) for _ in range(n_random_seeds)]
    return seeds


def _beyond_reach(model: ArmModel, T_t: F64, V: F64 | None, position_tol_m: float) -> IKResult | None:
    """``unreachable`` when the target lies farther from the base than the links can reach, else None."""
    reach = _reach_bound(model, V)
    distance = float(np.linalg.norm(T_t[:3, 3] - reach[0]))
    if distance > reach[1] + position_tol_m:
        return IKResult(
            False,
            "unreachable",
            None,
            f"target is {distance * 1e3:.1f} mm from the robot base, beyond the {reach[1] * 1e3:.1f} mm "
            "that the sum of its link lengths allows",
            distance - reach[1],
            float("nan"),
            0,
        )
    return None


@dataclass(frozen=True)
class _Acceptance:
    """Whether a configuration solves the problem: within the position tolerance and, unless the
    problem is ``position_only``, the rotation tolerance; with both errors."""

    prob: _Problem
    position_tol_m: float
    rotation_tol_rad: float

    def __call__(self, q: F64) -> tuple[bool, float, float]:
        ep, er = self.prob.errors(q)
        return ep <= self.position_tol_m and (self.prob.position_only or er <= self.rotation_tol_rad), ep, er


def _solve_within_limits(
    prob: _Problem, seeds: list[F64], good: _Acceptance, max_nfev: int
) -> tuple[IKResult | None, tuple[float, float, F64 | None]]:
    """One bounded solve per seed until one is accepted: (its ``ok`` result or None, the best miss
    ``(position error, rotation error, q)`` by ``position + rotation_weight_m * rotation`` error)."""
    lo, hi = prob.model.lower, prob.model.upper
    w = prob.w
    best: tuple[float, float, F64 | None] = (np.inf, np.inf, None)
    for k, s in enumerate(seeds, start=1):
        q = np.clip(prob.solve(s, (lo, hi), max_nfev), lo, hi)
        ok, ep, er = good(q)
        if ok:
            return IKResult(True, "ok", q, "ok", ep, er, k), best
        if ep + w * er < best[0] + w * best[1]:
            best = (ep, er, q)
    return None, best


def _solve_without_limits(
    prob: _Problem, seeds: list[F64], seed: F64, good: _Acceptance, max_nfev: int, attempts: int
) -> tuple[IKResult | None, int]:
    """The failure classification: unbounded solves from every seed, each solution wrapped by 2 pi
    towards the limits. Returns (an ``ok`` result if a wrapped one is within them, else the first
    ``out_of_limits`` one, else None; the attempts counted so far)."""
    model = prob.model
    lo, hi = model.lower, model.upper
    outside: IKResult | None = None
    for s in seeds:
        attempts += 1
        q = prob.solve(s, None, max_nfev)
        ok, ep, er = good(q)
        if not ok:
            continue
        qw = _wrap_into_limits(q, lo, hi, seed)
        if model.within_limits(qw):
            ok2, ep2, er2 = good(qw)
            if ok2:
                return IKResult(True, "ok", qw, "ok", ep2, er2, attempts), attempts
        if outside is None:
            violations = "; ".join(model.limit_violations(qw))
            outside = IKResult(
                False,
                "out_of_limits",
                qw,
                f"target reachable only outside the joint limits: {violations}",
                ep,
                er,
                attempts,
            )
    if outside is not None:
        return replace(outside, attempts=attempts), attempts
    return None, attempts


def solve_ik(
    model: ArmModel,
    T_world_tcp: ArrayLike,
    q_seed: ArrayLike | None = None,
    *,
    values: ArrayLike | None = None,
    position_only: bool = False,
    position_tol_m: float = 1e-6,
    rotation_tol_rad: float = 1e-6,
    n_random_seeds: int = 16,
    rng_seed: int = 0,
    rotation_weight_m: float = 0.2,
    max_nfev: int = 100,
    classify_failures: bool = True,
) -> IKResult:
    """Joint angles that put the TCP at ``T_world_tcp``, within the model's joint limits.

    Tries ``q_seed`` (default: the model's home) then ``n_random_seeds`` uniform random seeds drawn
    with ``rng_seed``. When no bounded solve converges and ``classify_failures`` is set, repeats
    without limits to tell ``out_of_limits`` from ``unreachable``. Raises ValueError for a
    malformed target or seed (NaN, not rigid, wrong length).
    """
    T_t = as_transform(T_world_tcp, name="IK target T_world_tcp")
    seed = model.home if q_seed is None else model.check_joints(q_seed, name="q_seed")[0][0]
    V = model.check_values(values, 1)
    prob = _Problem(model, T_t, V, position_only, rotation_weight_m)
    seeds = _seeds(model, seed, n_random_seeds, rng_seed)
    too_far = _beyond_reach(model, T_t, V, position_tol_m)
    if too_far is not None:
        return too_far
    good = _Acceptance(prob, position_tol_m, rotation_tol_rad)
    solved, best = _solve_within_limits(prob, seeds, good, max_nfev)
    if solved is not None:
        return solved
    attempts = len(seeds)
    if classify_failures:
        found, attempts = _solve_without_limits(prob, seeds, seed, good, max_nfev, attempts)
        if found is not None:
            return found
    ep, er, _ = best
    return IKResult(
        False,
        "unreachable",
        None,
        f"no joint configuration reaches the target: best position error {ep * 1e3:.3f} mm, "
        f"rotation error {np.degrees(er):.3f} deg after {attempts} attempts",
        float(ep),
        float(er),
        attempts,
    )
