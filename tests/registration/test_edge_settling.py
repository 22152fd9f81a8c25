"""A Gauss-Newton contour refinement that runs out of iterations while its steps stay within one sigma
of the estimate wanders in its own noise: it is converged (at the mean pose), on every CPU alike; one
whose steps still exceed a sigma is not."""

from __future__ import annotations

import numpy as np

from engine import transforms as tf
from plugins.registration.edges import WANDER_STEPS, settled


def wander(step2: list[float], seed: int = 0) -> list[tuple[np.ndarray, float]]:
    rng = np.random.default_rng(seed)
    base = tf.exp_se3(np.array([0.01, -0.02, 0.3, 0.0, 0.0, 0.2]))
    return [(tf.exp_se3(rng.normal(0, 1e-5, 6)) @ base, s) for s in step2]


def test_steps_within_a_sigma_settle_at_the_mean_pose():
    recent = wander([4.0, 2.0, *([0.5] * WANDER_STEPS)])
    T, ok = settled(recent, recent[-1][0])
    assert ok
    mean_t = np.mean([p[:3, 3] for p, _ in recent[-WANDER_STEPS:]], axis=0)
    np.testing.assert_allclose(T[:3, 3], mean_t, atol=1e-12)
    assert np.linalg.norm(T[:3, :3] @ recent[-1][0][:3, :3].T - np.eye(3)) < 1e-4


def test_a_step_above_a_sigma_or_too_few_steps_is_not_convergence():
    recent = wander([*([0.5] * (WANDER_STEPS - 1)), 1.5])
    assert settled(recent, recent[-1][0]) == (recent[-1][0], False)
    short = wander([0.2] * (WANDER_STEPS - 1))
    assert settled(short, short[-1][0])[1] is False
