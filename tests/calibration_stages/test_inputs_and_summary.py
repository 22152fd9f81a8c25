"""Pairing of sample streams, message -> library data conversions, and CalibrationResult.summary_rows."""

from __future__ import annotations

import numpy as np
import pytest
from calib_helpers import MOVEIT
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.messages import JointState, PoseStamped, TrackerPose
from plugins.calibration.handeye import calibrate_hand_eye, load_pose_pairs
from plugins.calibration.inputs import (
    CalibrationInputError,
    kinematic_samples,
    pair_by_stamp_or_order,
    vive_desk_data,
)
from plugins.calibration.result import CalibrationResult

S = 1_000_000_000


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 40),
    drops=st.sets(st.integers(0, 39)),
    jitter=st.lists(st.integers(-20_000_000, 20_000_000), min_size=40, max_size=40),
    extra=st.integers(0, 3),
)
def test_pairing_by_stamp_finds_the_partner_of_every_sample_it_can(n, drops, jitter, extra):
    primary = [k * S for k in range(n)]
    kept = [k for k in range(n) if k not in drops]
    secondary = [k * S + jitter[k] for k in kept] + [(n + 5 + j) * S for j in range(extra)]
    if len(kept) < n:
        with pytest.raises(CalibrationInputError, match=f"{n - len(kept)} of {n} a have no b within 0.05 s"):
            pair_by_stamp_or_order(primary, secondary, names=("a", "b"))
    if not kept:
        return
    p = pair_by_stamp_or_order(primary, secondary, names=("a", "b"), drop_unmatched=True)
    assert p.pairs == [(k, i) for i, k in enumerate(kept)]
    assert (len(kept) < n) == any("dropped" in note for note in p.notes)
    assert (extra > 0) == any("not paired" in note for note in p.notes)


def test_pairing_by_order_checks_counts_and_stamps():
    assert pair_by_stamp_or_order([1, 2], [1, 2], mode="order").pairs == [(0, 0), (1, 1)]
    with pytest.raises(CalibrationInputError, match="3 robot but 2 camera: pairing by order needs equal counts"):
        pair_by_stamp_or_order([1, 2, 3], [1, 2], mode="order", names=("robot", "camera"))
    with pytest.raises(CalibrationInputError, match=r"pair 1: .* \(2.000 s apart > max skew 0.05 s"):
        pair_by_stamp_or_order([0, S], [0, 3 * S], mode="order")
    assert pair_by_stamp_or_order([0, S], [0, 3 * S], mode="order", max_skew_s=None).pairs == [(0, 0), (1, 1)]


def test_conversions_drop_invalid_tracker_readings_and_check_joint_counts():
    contacts = [PoseStamped(T=np.eye(4), frame_id="desktop", stamp_ns=k * S) for k in range(4)]
    for k, c in enumerate(contacts):
        c.T[:3, 3] = [0.2 * (k % 2), 0.2 * (k // 2), 0.0]
    trackers = [TrackerPose(T=c.T.copy(), stamp_ns=c.stamp_ns, valid=True) for c in contacts]
    trackers.insert(2, TrackerPose(T=np.eye(4), stamp_ns=int(1.01 * S), valid=False))
    data, notes = vive_desk_data(contacts, trackers)
    assert data.n == 4 and "1 tracker reading(s) flagged invalid" in notes[0]
    joints = [JointState(positions=np.zeros(6 if k else 5), stamp_ns=k * S) for k in range(3)]
    points = [PoseStamped(stamp_ns=k * S) for k in range(3)]
    with pytest.raises(CalibrationInputError, match=r"different numbers of joints: \[5, 6\]"):
        kinematic_samples(joints, points)
    with pytest.raises(CalibrationInputError, match="no measurements"):
        kinematic_samples(joints, [])


def test_summary_rows_in_mm_and_degrees_with_one_sigma():
    s = load_pose_pairs(MOVEIT)
    res = calibrate_hand_eye(s.T_base_tcp, s.T_cam_target, setup="eye_to_hand")
    rows = {r.name: r for r in res.summary_rows()}
    std = res.std()
    assert rows["T_base_cam.x"].value == pytest.approx(res.estimate["T_base_cam"][0, 3] * 1e3)
    assert rows["T_base_cam.x"].sigma == pytest.approx(std["T_base_cam.tx"] * 1e3) and rows["T_base_cam.x"].unit == "mm"
    assert rows["T_base_cam.rotvec_z"].unit == "deg"
    assert rows["T_base_cam.rotvec_z"].sigma == pytest.approx(np.degrees(std["T_base_cam.rz"]))
    assert len(rows) == 12  # two transforms; the set-up string is no row
    bare = CalibrationResult(
        kind="kinematic",
        verdict="ok",
        estimate={
            "T_meas_base": np.eye(4),
            "offsets": {"joint2.a": 3e-4, "joint3.theta": 1e-3},
            "closed_form_T": np.eye(4),
        },
        param_names=["joint2.a", "joint3.theta"],
        covariance=np.diag([1e-10, 4e-8]),
    )
    rows = {r.name: r for r in bare.summary_rows()}
    assert rows["T_meas_base.x"].sigma is None and "closed_form_T.x" not in rows
    assert rows["joint2.a (change)"].value == pytest.approx(0.3) and rows["joint2.a (change)"].sigma == pytest.approx(
        0.01
    )
    assert rows["joint3.theta (change)"].unit == "deg"
    assert rows["joint3.theta (change)"].sigma == pytest.approx(np.degrees(2e-4))


def test_a_result_with_values_not_measured_is_strict_json_and_reads_back_as_nan():
    """``--no-holdout`` leaves the held-out figure NaN: written as null (strict parsers refuse a bare
    NaN), read back as NaN, in metrics and inside arrays alike."""
    import json

    res = CalibrationResult(
        kind="handeye",
        verdict="ok",
        estimate={"T_tcp_cam": np.eye(4), "per_view_px": np.array([0.4, np.nan])},
        param_names=["x", "y"],
        covariance=np.array([[1e-8, np.nan], [np.nan, 1e-8]]),
        metrics={"holdout_rms_px": float("nan"), "rms_px": 0.3},
    )
    text = res.to_json()

    def refuse(name: str) -> None:
        raise ValueError(f"not strict JSON: {name}")

    doc = json.loads(text, parse_constant=refuse)
    assert doc["metrics"]["holdout_rms_px"] is None and doc["covariance"][0][1] is None
    back = CalibrationResult.from_dict(doc)
    assert np.isnan(back.metrics["holdout_rms_px"]) and back.metrics["rms_px"] == 0.3
    assert np.isnan(back.covariance[0, 1]) and back.covariance.dtype == float
    assert np.isnan(back.estimate["per_view_px"][1]) and back.estimate["per_view_px"][0] == 0.4
