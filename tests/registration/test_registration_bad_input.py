"""Bad input never escapes the top-level matchers as an exception, never yields an estimate, and always
comes back as a ``failed`` result with a reason a person can act on."""

from __future__ import annotations

import numpy as np
import pytest
import registration_scenes as scenes
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from engine import transforms as tf
from plugins.registration import (
    FeatureFrameParams,
    FineParams,
    GlobalParams,
    PreprocessParams,
    register_feature_frame,
    register_fine,
    register_global,
)


def _good_cloud(n: int = 4000, seed: int = 0) -> np.ndarray:
    """A small box-like surface: three orthogonal 6 cm faces (a well-conditioned registration)."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(0.0, 0.06, (n, 2))
    k = n // 3
    faces = [
        np.column_stack([u[:k, 0], u[:k, 1], np.zeros(k)]),
        np.column_stack([u[k : 2 * k, 0], np.zeros(k), u[k : 2 * k, 1]]),
        np.column_stack([np.zeros(n - 2 * k), u[2 * k :, 0], u[2 * k :, 1]]),
    ]
    return np.vstack(faces) + np.array([0.0, 0.0, 0.5])


GOOD = _good_cloud()
MATCHERS = {
    "fine": lambda cur, tmpl: register_fine(cur, tmpl),
    "global": lambda cur, tmpl: register_global(cur, tmpl, GlobalParams(method="fpfh")),
    "feature_frame": lambda cur, tmpl: register_feature_frame(cur, tmpl, FeatureFrameParams()),
}


def _assert_failed_with_reason(result, *words: str) -> None:
    assert result.verdict == "failed", result.summary()
    assert result.T_match is None
    assert not result.usable
    assert result.reasons and all(isinstance(r, str) and r for r in result.reasons)
    text = " ".join(result.reasons).lower()
    for w in words:
        assert w in text, f"{w!r} not in {result.reasons}"


@pytest.mark.parametrize("matcher", sorted(MATCHERS))
@pytest.mark.parametrize(
    ("cloud", "words"),
    [
        (np.zeros((0, 3)), ("empty",)),
        (None, ("missing",)),
        (np.zeros((5, 3)), ("fewer than",)),
        (np.ones((100, 2)), ("shape",)),
        ([[0.0, 0.0, "a"]] * 50, ("real numbers",)),
        (np.full((500, 3), np.nan), ("nan",)),
        (np.vstack([GOOD, [[np.nan, 0.0, 0.5]]]), ("1 of", "nan")),
        (np.vstack([GOOD, [[np.inf, 0.0, 0.5]]]), ("nan/inf",)),
        (GOOD * 1e5, ("wrong units",)),
        (np.tile([[0.1, 0.2, 0.5]], (500, 1)), ("one spot",)),
        (np.column_stack([np.linspace(0, 0.1, 500), np.zeros(500), np.full(500, 0.5)]), ("line",)),
    ],
    ids=["empty", "none", "too-few", "2d", "strings", "all-nan", "one-nan", "inf", "km", "one-spot", "line"],
)
def test_bad_current_cloud_gives_failed_result(matcher, cloud, words):
    _assert_failed_with_reason(MATCHERS[matcher](cloud, GOOD), *words)


@pytest.mark.parametrize("matcher", ["fine", "global"])
def test_bad_template_cloud_names_the_template(matcher):
    _assert_failed_with_reason(MATCHERS[matcher](GOOD, np.zeros((0, 3))), "template", "empty")


@pytest.mark.parametrize(
    "T_init",
    [np.full((4, 4), np.nan), np.eye(3), np.diag([2.0, 1.0, 1.0, 1.0]), np.diag([1.0, 1.0, -1.0, 1.0])],
    ids=["nan", "3x3", "scaled", "reflection"],
)
def test_bad_initial_guess_gives_failed_result(T_init):
    _assert_failed_with_reason(register_fine(GOOD, GOOD, T_init), "t_init")


def test_unknown_backend_gives_failed_result():
    _assert_failed_with_reason(register_fine(GOOD, GOOD, None, FineParams(backend="teaser")), "unknown backend")


def test_drop_non_finite_opt_in_recovers_the_pose():
    """The current cloud is the template moved by 3 mm / 2 deg, plus NaN rows: dropped, the match
    finds the move (p_template = T_match @ p_current) instead of failing on the NaNs."""
    T_move = tf.T_from_rotvec(np.radians([0.0, 0.0, 2.0]), [0.003, -0.002, 0.001])
    moved = GOOD @ T_move[:3, :3].T + T_move[:3, 3]
    cur = np.vstack([moved, np.full((30, 3), np.nan)])
    res = register_fine(cur, GOOD, None, FineParams(preprocess=PreprocessParams(drop_non_finite=True)))
    assert res.verdict == "ok", res.summary()
    d_m, d_rad = tf.pose_error(res.T_match, np.linalg.inv(T_move))
    assert d_m < 1e-4 and np.degrees(d_rad) < 0.01


finite_or_not = st.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    hnp.arrays(
        np.float64,
        st.tuples(st.integers(0, 60), st.sampled_from([1, 2, 3, 4])),
        elements=finite_or_not,
    )
)
def test_arbitrary_arrays_never_raise_and_never_give_nan(cloud):
    for name, matcher in MATCHERS.items():
        res = matcher(cloud, GOOD)
        assert res.verdict in ("ok", "ambiguous", "failed"), name
        if res.T_match is not None:
            assert np.all(np.isfinite(res.T_match)), name
        if res.verdict == "failed":
            assert res.reasons, name


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 2**31 - 1), st.integers(20, 3000), st.floats(1e-4, 0.2))
def test_random_blobs_are_never_silently_matched_to_the_box(seed, n, spread):
    """Random point blobs are not the box: the result may be failed or ambiguous, never ok."""
    rng = np.random.default_rng(seed)
    blob = rng.normal(0.0, spread, (n, 3)) + np.array([0.0, 0.0, 0.5])
    for name in ("fine", "global"):
        res = MATCHERS[name](blob, GOOD)
        assert res.verdict != "ok", f"{name}: {res.summary()}"
        assert res.reasons, name


@pytest.fixture(scope="module")
def plate_scene():
    cam = scenes.camera(640, 480)
    rng = np.random.default_rng(11)
    tmpl = scenes.model_template("planar_plate", scenes.nominal_pose("planar_plate"), 0.0007, rng)
    return cam, rng, tmpl


def test_template_from_another_part_fails(plate_scene):
    """The current capture shows feature_part; the template is the planar plate."""
    cam, rng, tmpl = plate_scene
    cur = scenes.capture("feature_part", scenes.nominal_pose("feature_part"), cam, rng)
    for res in (
        register_global(cur.points, tmpl.points, GlobalParams(method="auto")),
        register_fine(cur.points, tmpl.points, scenes.true_match(tmpl, cur)),
    ):
        assert res.verdict == "failed", res.summary()
        assert res.T_match is None
        assert "wrong part" in " ".join(res.reasons)


def test_cloud_with_the_part_missing_fails(plate_scene):
    """The part is missing: the camera sees only the empty fixture (a flat table) where it should be."""
    cam, rng, tmpl = plate_scene
    table = scenes.flat_table(cam, rng)
    for res in (
        register_global(table, tmpl.points, GlobalParams(method="auto")),
        register_fine(table, tmpl.points, np.eye(4)),
    ):
        assert res.verdict == "failed", res.summary()
        assert res.T_match is None
        assert res.reasons


def test_a_non_finite_uncertainty_never_yields_an_ok_match(monkeypatch):
    """A NaN sigma passes every 'sigma > limit' comparison: the match must fail instead of being ok
    with an unknown uncertainty (guidance acts on 'ok' alone)."""
    from plugins.registration import fine

    real = fine.pose_uncertainty

    def nan_sigma(*args, **kwargs):
        unc = real(*args, **kwargs)
        unc.sigma_translation_m = np.full(3, np.nan)
        return unc

    monkeypatch.setattr(fine, "pose_uncertainty", nan_sigma)
    res = register_fine(GOOD, GOOD, None)
    assert res.verdict == "failed" and res.T_match is None, res.summary()
    assert "not finite" in res.reasons[0]
