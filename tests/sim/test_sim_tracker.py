"""Simulated Vive tracker: rate, jitter statistics, latency signature, dropouts, bad input."""

import math

import numpy as np
import pytest

from engine.transforms import T_from_rotvec, inv, log_so3
from plugins.sim.sensor_effects import TrackerEffects
from plugins.sim.tracker import SimulatedViveTracker, ViveTrackerModel

MM = 1e-3
STATIC = T_from_rotvec([0.2, -0.1, 0.5], [1.0, 0.5, 0.8])


def linear(v: np.ndarray, w: np.ndarray | None = None):
    """Trajectory moving at constant linear velocity v (m/s) and angular velocity w (rad/s)."""
    w = np.zeros(3) if w is None else w

    def T(t: float) -> np.ndarray:
        out = STATIC @ T_from_rotvec(w * t)
        out[:3, 3] += v * t
        return out

    return T


def test_rate_stamps_and_sequence():
    tracker = SimulatedViveTracker(lambda t: STATIC)
    samples = tracker.stream(2.0, 1.0, np.random.default_rng(0))
    assert len(samples) == 250
    stamps = np.array([s.stamp_ns for s, _ in samples])
    assert stamps[0] == 2_000_000_000
    np.testing.assert_array_equal(np.diff(stamps), 4_000_000)  # 250 Hz
    assert [s.seq for s, _ in samples] == list(range(250))
    assert all(s.valid for s, _ in samples)
    assert (
        len(
            SimulatedViveTracker(lambda t: STATIC, ViveTrackerModel(rate_hz=90.0)).stream(
                0, 1.0, np.random.default_rng(0)
            )
        )
        == 90
    )


def test_jitter_matches_the_model():
    model = ViveTrackerModel()  # 0.3 mm, 0.02 deg
    tracker = SimulatedViveTracker(lambda t: STATIC, model)
    samples = tracker.stream(0.0, 16.0, np.random.default_rng(1))
    n = len(samples)
    pos = np.array([s.T_lighthouse_tracker[:3, 3] for s, _ in samples]) - STATIC[:3, 3]
    rot = np.array([log_so3(STATIC[:3, :3].T @ s.T_lighthouse_tracker[:3, :3]) for s, _ in samples])
    tol = 4 / math.sqrt(2 * n)  # relative standard error of a standard deviation, 4 sigma
    np.testing.assert_allclose(pos.std(axis=0), model.position_sigma_m, rtol=tol)
    np.testing.assert_allclose(rot.std(axis=0), model.rotation_sigma_rad, rtol=tol)
    assert np.all(np.abs(pos.mean(axis=0)) < 4 * model.position_sigma_m / math.sqrt(n))
    # white: no correlation between consecutive samples
    r = np.corrcoef(pos[:-1, 0], pos[1:, 0])[0, 1]
    assert abs(r) < 4 / math.sqrt(n)


def test_extra_noise_effect_adds_in_quadrature():
    effects = TrackerEffects(extra_position_sigma_m=0.4 * MM)
    samples = SimulatedViveTracker(lambda t: STATIC, ViveTrackerModel(), effects).stream(
        0.0, 16.0, np.random.default_rng(2)
    )
    pos = np.array([s.T_lighthouse_tracker[:3, 3] for s, _ in samples])
    assert pos.std(axis=0).mean() == pytest.approx(0.5 * MM, rel=0.05)


@pytest.mark.parametrize("speed", [0.1, 0.5])
def test_latency_lag_is_velocity_times_latency(speed):
    latency = 0.025
    v = speed * np.array([0.6, 0.8, 0.0])
    w = np.array([0.0, 0.0, 0.4])
    tracker = SimulatedViveTracker(linear(v, w), ViveTrackerModel.ideal(), TrackerEffects(latency_s=latency))
    for sample, truth in tracker.stream(1.0, 0.2, np.random.default_rng(0)):
        lag = truth.T_lighthouse_tracker_at_stamp[:3, 3] - sample.T_lighthouse_tracker[:3, 3]
        np.testing.assert_allclose(lag, v * latency, atol=1e-12)  # |lag| = 2.5 mm at 0.1 m/s, 12.5 at 0.5
        angle_lag = log_so3(sample.T_lighthouse_tracker[:3, :3].T @ truth.T_lighthouse_tracker_at_stamp[:3, :3])
        np.testing.assert_allclose(angle_lag, w * latency, atol=1e-12)
        assert truth.measured_at_s == pytest.approx(sample.stamp_ns * 1e-9 - latency)


def test_latency_with_jitter_is_recovered_on_average():
    latency, speed = 0.02, 0.3
    v = np.array([speed, 0.0, 0.0])
    tracker = SimulatedViveTracker(linear(v), ViveTrackerModel(), TrackerEffects(latency_s=latency))
    samples = tracker.stream(0.0, 4.0, np.random.default_rng(3))
    lag = np.array([t.T_lighthouse_tracker_at_stamp[0, 3] - s.T_lighthouse_tracker[0, 3] for s, t in samples])
    assert lag.mean() == pytest.approx(speed * latency, abs=4 * 0.3 * MM / math.sqrt(len(lag)))


def test_dropouts_and_lost_tracking_give_invalid_samples_without_pose():
    tracker = SimulatedViveTracker(lambda t: STATIC, effects=TrackerEffects(dropout_prob=0.1))
    samples = tracker.stream(0.0, 20.0, np.random.default_rng(4))
    invalid = [s for s, _ in samples if not s.valid]
    assert len(invalid) / len(samples) == pytest.approx(0.1, abs=4 * math.sqrt(0.09 / len(samples)))
    assert all(s.T_lighthouse_tracker is None for s in invalid)
    assert [s.seq for s, _ in samples] == list(range(len(samples)))  # sequence continues across gaps
    occluded = SimulatedViveTracker(lambda t: None if 0.1 <= t < 0.2 else STATIC)
    states = [s.valid for s, _ in occluded.stream(0.0, 0.3, np.random.default_rng(0))]
    assert states == [not (0.1 <= k / 250 < 0.2) for k in range(75)]


def test_same_seed_same_stream():
    a = SimulatedViveTracker(lambda t: STATIC).stream(0.0, 0.1, np.random.default_rng(9))
    b = SimulatedViveTracker(lambda t: STATIC).stream(0.0, 0.1, np.random.default_rng(9))
    for (sa, _), (sb, _) in zip(a, b, strict=True):
        np.testing.assert_array_equal(sa.T_lighthouse_tracker, sb.T_lighthouse_tracker)


def test_bad_input_is_refused():
    scaled = STATIC.copy()
    scaled[:3, :3] *= 1.1
    with pytest.raises(ValueError, match="trajectory"):
        SimulatedViveTracker(lambda t: scaled).sample(0.0, np.random.default_rng(0))
    with pytest.raises(ValueError, match="NaN"):
        SimulatedViveTracker(lambda t: np.full((4, 4), np.nan)).sample(0.0, np.random.default_rng(0))
    with pytest.raises(TypeError, match="function"):
        SimulatedViveTracker(STATIC)
    with pytest.raises(TypeError, match="Generator"):
        SimulatedViveTracker(lambda t: STATIC).sample(0.0, 1)
    with pytest.raises(ValueError, match="finite"):
        SimulatedViveTracker(lambda t: STATIC).sample(float("nan"), np.random.default_rng(0))
    with pytest.raises(ValueError, match="duration"):
        SimulatedViveTracker(lambda t: STATIC).stream(0.0, -1.0, np.random.default_rng(0))
    for bad in (dict(rate_hz=0.0), dict(position_sigma_m=-1.0), dict(rotation_sigma_rad=float("nan"))):
        with pytest.raises(ValueError):
            ViveTrackerModel(**bad)
    with pytest.raises(ValueError, match=">= 0"):
        TrackerEffects(latency_s=-0.01)


def test_inverse_helper_consistency():
    """The tracker reports poses in the lighthouse frame: a static pose comes back unchanged."""
    tracker = SimulatedViveTracker(lambda t: STATIC, ViveTrackerModel.ideal())
    sample, truth = tracker.sample(0.3, np.random.default_rng(0))
    np.testing.assert_allclose(sample.T_lighthouse_tracker, STATIC, atol=1e-15)
    np.testing.assert_allclose(inv(sample.T_lighthouse_tracker) @ STATIC, np.eye(4), atol=1e-12)
    assert not truth.dropped
