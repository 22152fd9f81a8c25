"""Vive desk data files (JSON/CSV, m and mm) and bad input: NaN, too few or duplicated points,
non-rotations, millimetres, mixed units -> a clear error, never a silent wrong answer."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.transforms import T_from_rotvec, pose_error
from plugins.calibration.vive_desk import (
    ViveDeskData,
    calibrate_vive_desk,
    load_vive_csv,
    load_vive_json,
    save_vive_csv,
    save_vive_json,
)
from plugins.calibration.vive_desk.io import vive_to_json_dict
from plugins.calibration.vive_desk.simulate import SEED_POINTS_4, simulate_contacts, tilted_fixture_orientations


def multi_sim(seed=1, known=None):
    R = tilted_fixture_orientations()
    return simulate_contacts(
        np.vstack([SEED_POINTS_4] * 3),
        seed=seed,
        R_desktop_tcp=np.repeat(R, 4, axis=0),
        fixture_scatter_rad=np.radians(0.2),
        orientation_known=known,
    )


def same_result(a, b):
    for k in ("T_base_desktop", "T_tracker_tcp"):
        d_t, d_r = pose_error(a.estimate[k], b.estimate[k])
        assert d_t < 1e-9 and d_r < 1e-9


@pytest.mark.parametrize("fmt", ["json", "csv"])
def test_file_round_trip_gives_the_same_calibration(tmp_path, fmt):
    known = np.ones(12, bool)
    known[3] = False
    sim = multi_sim(known=known)
    path = tmp_path / f"contacts.{fmt}"
    (save_vive_json if fmt == "json" else save_vive_csv)(sim.data, path)
    data = (load_vive_json if fmt == "json" else load_vive_csv)(path)
    assert data.n == 12 and not data.orientation_known[3] and data.orientation_known.sum() == 11
    assert data.noise == sim.data.noise and data.labels == sim.data.labels
    same_result(calibrate_vive_desk(data), calibrate_vive_desk(sim.data))


def test_millimetre_file_equals_metre_file(tmp_path):
    sim = multi_sim()
    doc = vive_to_json_dict(sim.data)
    doc["units"] = "mm"
    for c in doc["contacts"]:
        for key in ("desk_point", "tracker_position", "tcp_offset"):
            c[key] = [v * 1000 for v in c[key]]
    doc["noise"]["tracker_position_sigma"] *= 1000
    (tmp_path / "mm.json").write_text(json.dumps(doc))
    data = load_vive_json(tmp_path / "mm.json")
    assert np.allclose(data.T_base_tracker, sim.data.T_base_tracker, atol=1e-12)
    assert data.noise.tracker_position_sigma_m == pytest.approx(sim.data.noise.tracker_position_sigma_m)


def test_seed_style_minimal_json(tmp_path):
    """The seed's own inputs: 3 points, contact_offset_z, one fixture orientation, poses."""
    sim = simulate_contacts(SEED_POINTS_4[:3], seed=2)
    doc = {
        "format": "vgr.vive_desk/1",
        "units": "m",
        "contact_offset_z": 0.12,
        "contacts": [
            {"desk_point": p.tolist(), "T_base_tracker": T.tolist()}
            for p, T in zip(sim.data.desk_points, sim.data.T_base_tracker, strict=True)
        ],
    }
    (tmp_path / "seed.json").write_text(json.dumps(doc))
    data = load_vive_json(tmp_path / "seed.json")
    assert np.allclose(data.tcp_offsets_desktop, [[0, 0, 0.12]] * 3)
    assert calibrate_vive_desk(data).verdict == "degenerate"


def test_file_errors_are_clear(tmp_path):
    sim = multi_sim()
    doc = vive_to_json_dict(sim.data)
    doc["contacts"][2]["tracker_quat_xyzw"] = [0.5, 0.5, 0.5, 0.2]
    (tmp_path / "q.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"contact 3.*norm"):
        load_vive_json(tmp_path / "q.json")
    doc = vive_to_json_dict(sim.data)
    doc["units"] = "inch"
    (tmp_path / "u.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="units"):
        load_vive_json(tmp_path / "u.json")
    (tmp_path / "c.csv").write_text("# units = m\ndesk_x,desk_y,tracker_x\n0,0,0\n")
    with pytest.raises(ValueError, match="lacks columns"):
        load_vive_csv(tmp_path / "c.csv")


# ----------------------------------------------------------------------------- bad input


finite = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 11), st.integers(0, 2), st.sampled_from(["desk", "pos", "rot"]))
def test_nan_anywhere_is_rejected(i, j, where):
    sim = multi_sim()
    P = sim.data.desk_points.copy()
    T = sim.data.T_base_tracker.copy()
    if where == "desk":
        P[i, j] = np.nan
    elif where == "pos":
        T[i, j, 3] = np.nan
    else:
        T[i, j, j] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        ViveDeskData.from_contacts(P, T)


@settings(max_examples=20, deadline=None)
@given(st.floats(0.01, 0.5), st.integers(0, 11))
def test_non_rotation_is_rejected(scale, i):
    T = multi_sim().data.T_base_tracker.copy()
    T[i, :3, :3] *= 1.0 + scale  # sheared/scaled "rotation"
    with pytest.raises(ValueError, match=rf"T_base_tracker rotation\[{i}\] is not a rotation"):
        ViveDeskData.from_contacts(multi_sim().data.desk_points, T)


def test_reflection_is_rejected():
    T = multi_sim().data.T_base_tracker.copy()
    T[0, :3, 2] *= -1
    with pytest.raises(ValueError, match="det"):
        ViveDeskData.from_contacts(multi_sim().data.desk_points, T)


def test_fewer_than_three_distinct_points():
    sim = simulate_contacts(np.array([[0, 0, 0], [0.2, 0, 0], [0.2, 0.0005, 0]]), seed=3)
    with pytest.raises(ValueError, match="at least 3 distinct contact points"):
        calibrate_vive_desk(sim.data)


def test_duplicated_row_is_rejected_but_repeated_contacts_are_averaged():
    sim = multi_sim()
    P = np.vstack([sim.data.desk_points, sim.data.desk_points[:1]])
    T = np.vstack([sim.data.T_base_tracker, sim.data.T_base_tracker[:1]])
    R = np.vstack([sim.data.R_desktop_tcp, sim.data.R_desktop_tcp[:1]])
    with pytest.raises(ValueError, match="identical"):
        calibrate_vive_desk(ViveDeskData.from_contacts(P, T, R_desktop_tcp=R))
    res = calibrate_vive_desk(sim.data)  # 4 points x 3 orientations: repeats of each point
    assert any("repeated contact" in r for r in res.reasons)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ("desk_mm", "desk points .* millimetres"),
        ("tracker_mm", "tracker positions .* millimetres"),
        ("offset_mm", "contact offset .* millimetres"),
        ("mixed", r"mixed units.*ratio 0\.1"),
    ],
)
def test_millimetres_and_mixed_units_are_detected(change, match):
    sim = multi_sim()
    d = sim.data
    P, T, off = d.desk_points.copy(), d.T_base_tracker.copy(), d.tcp_offsets_desktop.copy()
    if change == "desk_mm":
        P *= 1000
    elif change == "tracker_mm":
        T[:, :3, 3] *= 1000
    elif change == "offset_mm":
        off *= 1000
    else:  # a scale mismatch small enough to pass every magnitude check (real mm-vs-m mixes are
        P *= 10  # caught by the magnitudes above); only the rigid-desk ratio can see it
    data = ViveDeskData.from_contacts(P, T, tcp_offsets_desktop=off, R_desktop_tcp=d.R_desktop_tcp)
    with pytest.raises(ValueError, match=match):
        calibrate_vive_desk(data)


@settings(max_examples=8, deadline=None)
@given(st.tuples(finite, finite, finite), st.tuples(finite, finite, finite))
def test_moving_the_base_station_moves_only_T_base_desktop(rv, t):
    """Equivariance: re-expressing all tracker poses in another base frame W changes T_base_desktop
    to T_W_base @ T_base_desktop and leaves T_tracker_tcp unchanged."""
    sim = multi_sim(seed=4)
    T_WB = T_from_rotvec(np.array(rv) * 3, np.array(t))
    T_moved = np.einsum("ij,njk->nik", T_WB, sim.data.T_base_tracker)
    d = sim.data
    moved = ViveDeskData.from_contacts(d.desk_points, T_moved, R_desktop_tcp=d.R_desktop_tcp, noise=d.noise)
    a, b = calibrate_vive_desk(d), calibrate_vive_desk(moved)
    dt, dr = pose_error(T_WB @ a.estimate["T_base_desktop"], b.estimate["T_base_desktop"])
    assert dt < 1e-7 and dr < 1e-7
    dt, dr = pose_error(a.estimate["T_tracker_tcp"], b.estimate["T_tracker_tcp"])
    assert dt < 1e-7 and dr < 1e-7
