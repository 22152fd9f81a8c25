"""Trapezoidal velocity profiles (the simulated controller's time law), vectorised in time.

A move of length ``distance`` with speed limit ``v_max`` and acceleration limit ``a_max`` accelerates,
cruises and decelerates; short moves never reach ``v_max`` and become triangular. Duration:
``distance / v_max + v_max / a_max`` with a cruise phase, ``2 sqrt(distance / a_max)`` without.

A move halted part-way (:meth:`TrapezoidProfile.halted`, the controller's stop) follows its profile
until the halt, then decelerates at ``a_max`` to rest short of ``distance``: the stop a controller
makes on its path (URScript ``stopj``/``stopl`` with the move's own deceleration).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class TrapezoidProfile:
    """Position ``s(t)`` from 0 to ``distance`` over ``duration`` seconds (t measured from the start)."""

    distance: float
    v_peak: float
    a_max: float
    t_accel: float
    t_cruise: float

    @property
    def duration(self) -> float:
        return 2.0 * self.t_accel + self.t_cruise

    def position(self, t: ArrayLike) -> F64:
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.duration)
        ta, tc, a, v = self.t_accel, self.t_cruise, self.a_max, self.v_peak
        s_acc = 0.5 * a * ta**2
        t_dec = t - ta - tc
        s = np.where(
            t < ta,
            0.5 * a * t**2,
            np.where(t < ta + tc, s_acc + v * (t - ta), s_acc + v * tc + v * t_dec - 0.5 * a * t_dec**2),
        )
        return np.minimum(s, self.distance) if self.distance > 0 else np.zeros_like(t)

    def velocity(self, t: ArrayLike) -> F64:
        t = np.asarray(t, dtype=float)
        ta, tc, a, v = self.t_accel, self.t_cruise, self.a_max, self.v_peak
        vel = np.where(t < ta, a * t, np.where(t < ta + tc, v, v - a * (t - ta - tc)))
        return np.where((t <= 0) | (t >= self.duration), 0.0, vel)

    def halted(self, t_halt: float) -> HaltedProfile:
        """This profile stopped at *t_halt* (from the start): it decelerates from there at ``a_max``."""
        t_h = float(np.clip(t_halt, 0.0, self.duration))
        return HaltedProfile(self, t_h, float(self.position(t_h)), float(self.velocity(t_h)))


@dataclass(frozen=True)
class HaltedProfile:
    """*base* until ``t_halt``, then a stop at ``base.a_max`` from ``v_halt``; at rest at ``distance``."""

    base: TrapezoidProfile
    t_halt: float
    s_halt: float
    v_halt: float

    @property
    def a_max(self) -> float:
        return self.base.a_max

    @property
    def duration(self) -> float:
        return self.t_halt + self.v_halt / self.base.a_max

    @property
    def distance(self) -> float:
        """Where it comes to rest (at most the base's distance: a stop never overshoots)."""
        return min(self.s_halt + 0.5 * self.v_halt**2 / self.base.a_max, self.base.distance)

    def halted(self, t_halt: float) -> HaltedProfile:
        """Already stopping, at the fastest deceleration there is: a second halt changes nothing."""
        return self

    def position(self, t: ArrayLike) -> F64:
        t = np.asarray(t, dtype=float)
        dt = np.clip(t - self.t_halt, 0.0, self.duration - self.t_halt)
        braking = np.minimum(self.s_halt + self.v_halt * dt - 0.5 * self.base.a_max * dt**2, self.distance)
        return np.where(t <= self.t_halt, self.base.position(t), braking)

    def velocity(self, t: ArrayLike) -> F64:
        t = np.asarray(t, dtype=float)
        braking = np.maximum(self.v_halt - self.base.a_max * (t - self.t_halt), 0.0)
        vel = np.where(t <= self.t_halt, self.base.velocity(t), braking)
        return np.where((t <= 0) | (t >= self.duration), 0.0, vel)


Profile = TrapezoidProfile | HaltedProfile


def trapezoid(distance: float, v_max: float, a_max: float) -> TrapezoidProfile:
    """The time-optimal trapezoid (or triangle) for a rest-to-rest move."""
    if not (np.isfinite(distance) and distance >= 0):
        raise ValueError(f"distance must be finite and >= 0, got {distance}")
    if not (np.isfinite(v_max) and v_max > 0 and np.isfinite(a_max) and a_max > 0):
        raise ValueError(f"speed and acceleration limits must be > 0, got v={v_max}, a={a_max}")
    if distance == 0:
        return TrapezoidProfile(0.0, 0.0, a_max, 0.0, 0.0)
    t_acc = v_max / a_max
    if a_max * t_acc**2 >= distance:  # triangle: never reaches v_max
        t_acc = float(np.sqrt(distance / a_max))
        return TrapezoidProfile(distance, a_max * t_acc, a_max, t_acc, 0.0)
    return TrapezoidProfile(distance, v_max, a_max, t_acc, (distance - a_max * t_acc**2) / v_max)
