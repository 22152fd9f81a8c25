"""The camera model-gap workflow on simulated detections (plugins/sim/model_gap/camera_views.py):
each catalog effect hidden is named, held-out reprojection shrinks to the noise; nothing hidden gives
``no_gap``; effects the views cannot tell apart give a tie; a board that is not flat is named
``board_shape``, and with the lens effects alone (a catalog that lacks it) it is ``unexplained`` with
nothing named. The lens-effect cases run on :data:`LENS_EFFECTS` (releasing the board points costs a
``cv2.calibrateCameraRO`` per fold); the full catalog runs on a bowed board and on nothing hidden."""

from __future__ import annotations

import jsonschema
import numpy as np
import pytest

from plugins.model_gap.camera.catalog import CATALOG, LENS_EFFECTS
from plugins.model_gap.camera.report import report_dict, schema
from plugins.model_gap.camera.workflow import CameraGapConfig, run_camera_gap
from plugins.sim.model_gap.camera_views import SIM_BOARD, simulate_detections

LENS = CameraGapConfig(catalog=LENS_EFFECTS)
NOISE_PX = 0.1
FLOOR_PX = NOISE_PX * np.sqrt(2.0)  # RMS reprojection distance of pure corner noise


@pytest.mark.parametrize("effect", [e.name for e in LENS_EFFECTS])
def test_each_hidden_effect_is_named_and_the_held_out_error_shrinks_to_the_noise(effect):
    views, size = simulate_detections(effect, scale=4.0, seed=1, noise_px=NOISE_PX)
    r = run_camera_gap(views, size, LENS)
    assert r.verdict == "explained", (r.verdict, r.reason)
    assert r.named == [effect], [a.label for a in r.added]
    assert r.baseline_cv.rms_px > 1.4 * FLOOR_PX  # the effect was visible ...
    assert r.final_cv.rms_px < 1.03 * FLOOR_PX  # ... and is gone on held-out views
    assert r.structure_before.p_value < 1e-3 and r.structure_after.p_value > 1e-3


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_nothing_hidden_names_nothing(seed):
    views, size = simulate_detections(None, seed=seed, noise_px=NOISE_PX)
    r = run_camera_gap(views, size, LENS)
    assert r.verdict == "no_gap" and not r.added, r.reason
    assert all(not s.eligible for rd in r.rounds for s in rd.scores)
    assert r.final_cv.rms_px == r.baseline_cv.rms_px


def test_a_faint_decentring_is_a_tie_of_the_three_lookalikes_not_a_name():
    """At scale 1 tangential distortion, a thin prism and a tilted sensor each shift the principal
    point to first order: the held-out views cannot tell them apart, so none is named."""
    views, size = simulate_detections("tangential", scale=1.0, seed=0, noise_px=NOISE_PX)
    r = run_camera_gap(views, size, LENS)
    assert r.verdict == "explained_up_to_tie", r.reason
    assert r.named == []
    (term,) = r.added
    assert {term.effect.name, *(e.name for e in term.tied_with)} == {"tangential", "thin_prism", "tilted"}
    assert "tied" in r.reason or "tie" in r.reason
    assert r.final_cv.rms_px < 1.03 * FLOOR_PX


def test_a_hidden_k3_is_named_by_parsimony_over_the_rational_model():
    views, size = simulate_detections("radial_k3", scale=1.0, seed=0, noise_px=NOISE_PX)
    r = run_camera_gap(views, size, LENS)
    assert r.named == ["radial_k3"]
    assert [e.name for e in r.added[0].parsimony_over] == ["rational"]
    assert "parsimony" in r.rounds[0].decision.reason


def test_a_board_that_is_not_flat_is_unexplained_without_board_shape_in_the_catalog():
    views, size = simulate_detections(None, board_bow_m=1e-3, seed=0, noise_px=NOISE_PX)
    r = run_camera_gap(views, size, LENS)
    assert r.verdict == "unexplained" and r.named == [], r.reason
    assert r.structure_after.neighbours.p_value < 1e-6
    assert "smooth over the board" in r.reason


def test_a_board_that_is_not_flat_is_named_board_shape_with_the_full_catalog():
    views, size = simulate_detections(None, board_bow_m=1e-3, seed=0, noise_px=NOISE_PX)
    r = run_camera_gap(views, size)
    assert r.config.catalog == CATALOG
    assert r.verdict == "explained" and r.named == ["board_shape"], r.reason
    bow = r.final_fit.board_points[:, 2]
    assert bow.max() - bow.min() == pytest.approx(1e-3, abs=1e-4)  # the released board is 1 mm deep
    assert r.baseline_cv.rms_px > 1.8 * FLOOR_PX and r.final_cv.rms_px < 1.06 * FLOOR_PX
    doc = report_dict(r, board=SIM_BOARD)
    jsonschema.validate(doc, schema())
    assert doc["board_shape"]["out_of_plane_span_mm"] == pytest.approx(1.0, abs=0.1)
    assert doc["effects_added"][0]["effect"] == "board_shape" and not doc["effects_added"][0]["tied"]


def test_the_full_catalog_names_nothing_when_nothing_is_hidden():
    views, size = simulate_detections(None, seed=4, noise_px=NOISE_PX)
    r = run_camera_gap(views, size)
    assert r.verdict == "no_gap" and not r.added, r.reason
    assert "board_shape" in [s.effect.name for s in r.rounds[0].scores]


def test_the_effect_limit_leaves_the_gap_unexplained():
    views, size = simulate_detections("tilted", scale=4.0, seed=1, noise_px=NOISE_PX)
    r = run_camera_gap(views, size, CameraGapConfig(max_effects=0, catalog=LENS_EFFECTS))
    assert r.verdict == "unexplained" and not r.added
    assert "--max-effects 0" in r.reason
