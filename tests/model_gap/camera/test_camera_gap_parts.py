"""The parts of the camera gap: each catalog effect's OpenCV flags free exactly its coefficients,
the paired test and the folds, the structure tests' behaviour on noise and on a systematic field."""

from __future__ import annotations

import numpy as np
import pytest

from plugins.model_gap.camera.catalog import (
    BASELINE,
    CATALOG,
    COEFFICIENTS,
    LENS_EFFECTS,
    calibrate_flags,
    effect_by_name,
)
from plugins.model_gap.camera.crossval import cross_validate, view_folds
from plugins.model_gap.camera.fitting import fit_views, fixed_board_point
from plugins.model_gap.camera.selection import paired_gain
from plugins.model_gap.camera.structure import neighbour_structure, residual_structure
from plugins.sim.model_gap.camera_views import simulate_detections, true_distortion


@pytest.fixture(scope="module")
def tilted_views():
    return simulate_detections("tilted", scale=4.0, seed=5, noise_px=0.05)


@pytest.mark.parametrize("effect", [e.name for e in CATALOG])
def test_the_flags_of_an_effect_free_exactly_its_coefficients(effect, tilted_views):
    views, size = tilted_views
    free = BASELINE | set(effect_by_name(effect).coefficients)
    fit = fit_views(views, size, free)
    fixed = [c for c in COEFFICIENTS if c not in free]
    assert np.all(fit.D[[COEFFICIENTS.index(c) for c in fixed]] == 0.0), fit.D
    assert all(fit.coefficients()[c] != 0.0 for c in free if c in COEFFICIENTS)
    released = effect_by_name(effect).releases_board
    assert (fit.board_points is not None) == released
    if released:  # cv2.calibrateCameraRO holds the first point and the end of the first row
        held = [0, fixed_board_point(views)]
        assert np.allclose(fit.board_points[held], views[0].object_points[held], atol=1e-7)
        assert abs(fit.board_points[-1, 2]) < 1e-9  # and the last point's height


def test_the_true_tilt_is_recovered_and_partial_groups_are_refused(tilted_views):
    views, size = tilted_views
    fit = fit_views(views, size, BASELINE | {"tauX", "tauY"})
    truth = true_distortion("tilted", 4.0)
    assert fit.D[12:] == pytest.approx(truth[12:], abs=1e-3)
    for bad in ({"p1"}, {"s1", "s2"}, {"tauX"}, {"k9"}):
        with pytest.raises(ValueError):
            calibrate_flags(BASELINE | bad)


def test_folds_partition_the_views_and_are_seeded():
    folds = view_folds(23, 5, seed=4)
    assert sorted(np.concatenate(folds).tolist()) == list(range(23))
    assert [len(f) for f in folds] == [5, 5, 5, 4, 4]
    assert all((a == b).all() for a, b in zip(folds, view_folds(23, 5, seed=4), strict=True))
    with pytest.raises(ValueError):
        view_folds(3, 5, seed=0)


def test_the_paired_test_sees_a_real_gain_and_not_an_identical_model(tilted_views):
    views, size = tilted_views
    folds = view_folds(len(views), 5, 0)
    base = cross_validate(views, size, BASELINE, folds)
    tilt = cross_validate(views, size, BASELINE | {"tauX", "tauY"}, folds, base)
    assert paired_gain(base, base).p_value == 1.0
    gain = paired_gain(base, tilt)
    assert gain.p_value < 1e-4 and gain.n_better == len(views)
    assert paired_gain(tilt, base).p_value > 0.99


def test_the_structure_tests_hold_their_level_on_noise_and_see_a_field():
    """On pure noise residuals both tests hold their level (at most 10 of 120 p-values below 0.05:
    8 %, a binomial tail of 7 % at the nominal 5 %); a field common to all views is found by both."""
    views, size = simulate_detections(None, seed=7, n_views=12)
    rng = np.random.default_rng(11)
    p_field, p_nb = [], []
    for _ in range(120):
        noise = [rng.normal(0.0, 0.1, (v.n, 2)) for v in views]
        p_field.append(residual_structure(views, noise, size, seed=1).p_value)
        p_nb.append(neighbour_structure(views, noise).p_value)
    assert sum(p < 0.05 for p in p_field) <= 10 and sum(p < 0.05 for p in p_nb) <= 10, (p_field, p_nb)
    field = [rng.normal(0.0, 0.1, (v.n, 2)) + 0.3 * (v.image_points - (640.0, 480.0)) / 640.0 for v in views]
    assert residual_structure(views, field, size, seed=1).p_value < 1e-3
    assert neighbour_structure(views, field).p_value < 1e-3


def test_a_candidate_whose_fit_fails_is_left_out_not_a_crash(monkeypatch):
    """OpenCV refusing one candidate (cv2.error in a fold) makes it ineligible with the reason; the
    others are scored as usual."""
    import cv2

    from plugins.model_gap.camera import crossval, workflow

    real = crossval.fit_nested

    def failing(train, size, free, warm):
        if "tauX" in free:
            raise cv2.error("simulated refusal")
        return real(train, size, free, warm)

    monkeypatch.setattr(crossval, "fit_nested", failing)
    views, size = simulate_detections("tangential", scale=4.0, seed=1)
    r = workflow.run_camera_gap(views, size, workflow.CameraGapConfig(catalog=LENS_EFFECTS))
    tilted = next(s for s in r.rounds[0].scores if s.effect.name == "tilted")
    assert not tilted.eligible and "failed" in tilted.reason
    assert r.named == ["tangential"]
