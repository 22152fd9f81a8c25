"""Sample instances of every registered message type, and what their wire form and decode look like.

``message_wire_golden.json`` beside this file was written by running this module
(``python tests/engine_core/message_wire_samples.py``) with the message classes as they were when
each one hand-wrote its ``to_proto`` / ``from_proto``; test_message_wire_golden.py checks that the
message classes of today give the same bytes and decode to the same values, types and dtypes.
Regenerate it only for an intended change of the wire format (which golden recordings would show too).
"""

from __future__ import annotations

import json
import sys
from dataclasses import is_dataclass
from pathlib import Path
from typing import Any

import numpy as np

from engine import messages as m
from engine import transforms as tf
from engine.messages import codec
from plugins.actions.messages import GuidanceResult
from plugins.registration.messages import MatchResult

GOLDEN = Path(__file__).resolve().with_name("message_wire_golden.json")


def _T(rotvec: tuple[float, float, float], t: tuple[float, float, float]) -> np.ndarray:
    return tf.T_from_rotvec(np.array(rotvec), np.array(t))


def samples() -> dict[str, m.Message]:
    """Named sample messages: every registered type, with the branches of its encoding (optional
    fields set and not, empty and non-empty repeated fields, odd dtypes and layouts)."""
    rng = np.random.default_rng(7)
    pts32 = rng.normal(size=(5, 3)).astype(np.float32)
    wide = rng.normal(size=(4, 4)).astype(np.float32)
    T1 = _T((0.1, -0.2, 0.3), (1.0, 2.0, 3.0))
    T2 = _T((3.0, 0.1, -0.05), (-0.25, 0.5, 0.125))
    T3 = _T((0.0, 0.0, np.pi), (0.0, 0.0, 0.0))
    out: dict[str, m.Message] = {
        "PointCloud/default": m.PointCloud(),
        "PointCloud/xyz32": m.PointCloud(points=pts32, frame_id="camera", stamp_ns=1_700_000_000_123_456_789),
        "PointCloud/xyz64_strided": m.PointCloud(points=rng.normal(size=(3, 6))[:, ::2], stamp_ns=5),
        "PointCloud/xyz32_noncontiguous": m.PointCloud(points=wide[:, :3], frame_id="c"),
        "PointCloud/normals_colors": m.PointCloud(
            points=pts32, normals=rng.normal(size=(5, 3)), colors=rng.integers(0, 256, size=(5, 3)), stamp_ns=9
        ),
        "PointCloud/colors64": m.PointCloud(
            points=rng.normal(size=(2, 3)), colors=np.array([[1, 2, 3], [250, 251, 252]]), frame_id="f"
        ),
        "Image/default": m.Image(),
        "Image/depth": m.Image(data=np.arange(12, dtype=np.float32).reshape(3, 4), frame_id="cam", stamp_ns=11),
        "Image/depth_nan": m.Image(data=np.full((2, 2), np.nan, np.float32), frame_id="cam"),
        "Image/rgb8": m.Image(data=np.arange(24, dtype=np.uint8).reshape(2, 4, 3), encoding="rgb8", stamp_ns=3),
        "Image/16UC1": m.Image(data=np.arange(6, dtype=np.uint16).reshape(2, 3), encoding="16UC1"),
        "Image/64FC1_fortran": m.Image(data=np.asfortranarray(rng.normal(size=(3, 2))), encoding="64FC1"),
        "CameraInfo/default": m.CameraInfo(),
        "CameraInfo/full": m.CameraInfo(
            width=640,
            height=480,
            K=np.array([[500, 0, 320], [0, 501.5, 240], [0, 0, 1]]),
            D=[0.1, -0.01, 0.0, 0.001, 0.0],
            distortion_model="rational_polynomial",
            frame_id="cam",
            stamp_ns=2_000_000_001,
        ),
        "PoseStamped/default": m.PoseStamped(),
        "PoseStamped/rotated": m.PoseStamped(T=T1, frame_id="base", stamp_ns=42),
        "PoseStamped/half_turn": m.PoseStamped(T=T3, frame_id="base"),
        "PoseWithCovarianceStamped/default": m.PoseWithCovarianceStamped(),
        "PoseWithCovarianceStamped/full": m.PoseWithCovarianceStamped(
            T=T2, covariance=np.diag([1e-8, 2e-8, 9e-8, 1e-6, 2e-6, 3e-6]) + 1e-9, frame_id="camera", stamp_ns=43
        ),
        "Transform/default": m.Transform(),
        "Transform/rotated": m.Transform(frame_id="base", child_frame_id="tcp", T=T2, stamp_ns=1_000_000_000),
        "FrameTransforms/empty": m.FrameTransforms(stamp_ns=99),
        "FrameTransforms/two": m.FrameTransforms(
            stamp_ns=7,
            frame_id="ignored",
            transforms=[
                m.Transform(frame_id="a", child_frame_id="b", T=T1, stamp_ns=5),
                m.Transform(frame_id="b", child_frame_id="c", T=T3, stamp_ns=6),
            ],
        ),
        "JointState/empty": m.JointState(),
        "JointState/unnamed": m.JointState(positions=np.array([0.1, -0.2, 0.3]), stamp_ns=8),
        "JointState/velocities": m.JointState(
            names=["j1", "j2"], positions=[0.5, 1], velocities=np.zeros(2), frame_id="f"
        ),
        "JointState/all": m.JointState(
            names=["a", "b"], positions=np.array([0.0, 2.0]), velocities=[1.0, -1.0], efforts=np.array([3.5, 0.0])
        ),
        "SceneMeshes/empty": m.SceneMeshes(stamp_ns=4),
        "SceneMeshes/two": m.SceneMeshes(
            stamp_ns=3_000_000_005,
            meshes=[
                m.Mesh("part", "base", np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.5]]), np.array([[0, 1, 2]])),
                m.Mesh(
                    "fixture",
                    "world",
                    np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 1]], dtype=np.float32),
                    np.array([[0, 1, 2], [1, 3, 2]], dtype=np.int32),
                    (0.1, 0.2, 0.3, 0.5),
                ),
            ],
        ),
        "Blob/default": m.Blob(),
        "Blob/bytes": m.Blob(data=bytes(range(256)), content_type="application/octet-stream", frame_id="x", stamp_ns=1),
        "Blob/memoryview": m.Blob(data=memoryview(bytearray(b"abc\x00def")), content_type="text/plain"),
        "Blob/array_view": m.Blob(data=memoryview(np.arange(4, dtype=np.uint16))),
        "TrackerPose/default": m.TrackerPose(),
        "TrackerPose/full": m.TrackerPose(
            serial="LHR-1", T=T2, valid=False, tracking_result="Running_OutOfRange", frame_id="lh", stamp_ns=6
        ),
        "Event/default": m.Event(),
        "Event/full": m.Event(
            level="alarm",
            code="stage_exception",
            stage="s",
            message="hello",
            traceback="tb",
            details={"b": np.arange(3), "a": np.float64(1.5), "c": {"x": [1, 2]}, "d": ValueError("odd")},
            stamp_ns=12,
        ),
        "CalibrationResultMsg/default": m.CalibrationResultMsg(),
        "CalibrationResultMsg/full": m.CalibrationResultMsg(
            kind="handeye",
            verdict="ok",
            method="park",
            reasons=["r1", "r2"],
            transforms={"T_tcp_cam": T1, "T_base_target": np.eye(4)},
            metrics={"rms_mm": 0.1, "count": 3, "np": np.float32(0.25)},
            result_json='{"x": 1}',
            stamp_ns=13,
            frame_id="ignored",
        ),
        "RobotCommand/default": m.RobotCommand(),
        "RobotCommand/move_l": m.RobotCommand(
            command_id="c1", kind="move_l", T=T1, speed=0.25, acceleration=1, comment="go", frame_id="base", stamp_ns=1
        ),
        "RobotCommand/move_j": m.RobotCommand(command_id="c2", kind="move_j", joints=[0.0, 1.0, -1.5], speed=2),
        "RobotCommand/empty_joints": m.RobotCommand(kind="stop", joints=np.zeros(0)),
        "RobotReply/default": m.RobotReply(),
        "RobotReply/full": m.RobotReply(
            command_id="c1",
            ok=True,
            error="",
            T=T2,
            joints=np.arange(6, dtype=np.float32),
            duration_s=1.25,
            duplicate=True,
            frame_id="base",
            stamp_ns=77,
        ),
        "RobotReply/error": m.RobotReply(command_id="c3", error="limit", duration_s=3),
        "Correction/default": m.Correction(),
        "Correction/full": m.Correction(
            kind="delta_tool", T=_T((0, 0, 0.01), (0.001, 0, 0)), verdict="refused", reasons=["r"], frame_id="tool"
        ),
        "Correction/half_turn": m.Correction(kind="delta_base", T=T3, stamp_ns=2),
        "Request/default": m.Request(),
        "Request/full": m.Request(command="capture", args={"z": 1, "exposure": np.float64(3.5), "arr": np.ones(2)}),
        "CellReply/default": m.CellReply(),
        "CellReply/full": m.CellReply(status="ok", message="located", result={"found": 1, "parts": [{"x": 0.25}]}),
        "MatchResult/default": MatchResult(),
        "MatchResult/ok": MatchResult(
            method="icp",
            verdict="ok",
            reasons=["fine"],
            T_match=T1,
            fitness=0.9,
            inlier_rmse_m=0.001,
            sigma=[1e-4, 2e-4, 3e-4, 1e-3, 2e-3, 3e-3],
            score_gap=0.5,
            result_json='{"verdict": "ok"}',
            frame_id="camera",
            stamp_ns=14,
        ),
        "MatchResult/failed_sigma": MatchResult(verdict="failed", sigma=np.arange(6, dtype=np.float32), fitness=1),
        "GuidanceResult/default": GuidanceResult(),
        "GuidanceResult/full": GuidanceResult(
            mode="eye_to_hand",
            verdict="converged",
            reasons=["a", "b"],
            T_start=T1,
            T_end=T2,
            moves=3,
            residual_mm=[1.5, np.float64(0.25), 1],
            residual_deg=[0.5, np.float32(0.125)],
            match_verdicts=["ok", "ok", "failed"],
            job=2**40,
            matches=[T1, T3],
            translation_tol_mm=0.5,
            rotation_tol_deg=0.1,
            frame_id="base",
            stamp_ns=15,
        ),
    }
    return out


def describe(v: Any) -> Any:
    """A JSON description of a decoded value that tells its type, dtype, shape and exact contents."""
    if v is None:
        return None
    if isinstance(v, np.ndarray):
        return {
            "ndarray": v.dtype.str,
            "shape": list(v.shape),
            "writeable": bool(v.flags.writeable),
            "hex": np.ascontiguousarray(v).tobytes().hex(),
        }
    if isinstance(v, bytes | bytearray | memoryview):
        return {type(v).__name__: bytes(v).hex()}
    if isinstance(v, str):
        return {"str": v}
    if isinstance(v, bool | np.bool_):
        return {type(v).__name__: bool(v)}
    if isinstance(v, int | np.integer):
        return {type(v).__name__: int(v)}
    if isinstance(v, float | np.floating):
        return {type(v).__name__: float(v).hex()}
    if isinstance(v, list | tuple):
        return {type(v).__name__: [describe(x) for x in v]}
    if isinstance(v, dict):
        return {"dict": [[k, describe(x)] for k, x in v.items()]}
    if is_dataclass(v):
        return {type(v).__name__: {k: describe(x) for k, x in vars(v).items()}}
    raise TypeError(f"cannot describe {type(v).__name__}")


def wire_form(msg: m.Message) -> dict[str, Any]:
    """The encoding of *msg* and the three ways it decodes: the protobuf handed over as is (what
    canonical() does), the payload parsed whole, and the payload split around its bulk field."""
    cls = type(msg)
    pb, bulk = msg.to_proto()
    payload = codec.encode_payload(msg)
    whole = cls.proto()
    whole.ParseFromString(payload)
    rest, split_bulk = (
        codec._split_bulk(memoryview(payload).cast("B"), cls.BULK) if cls.BULK is not None else (payload, None)
    )
    split = cls.proto()
    split.ParseFromString(bytes(rest))
    return {
        "type": cls.TYPE,
        "proto_hex": pb.SerializeToString(deterministic=True).hex(),
        "bulk_hex": None if bulk is None else bytes(bulk).hex(),
        "payload_hex": payload.hex(),
        "decoded_handed_over": describe_message(cls.from_proto(pb, bulk)),
        "decoded_whole": describe_message(cls.from_proto(whole, None)),
        "decoded_split": describe_message(cls.from_proto(split, split_bulk)),
    }


def describe_message(msg: m.Message) -> dict[str, Any]:
    return {"class": type(msg).__name__, "fields": {k: describe(v) for k, v in vars(msg).items()}}


def main() -> None:
    table = {name: wire_form(msg) for name, msg in samples().items()}
    GOLDEN.write_text(json.dumps(table, indent=1, sort_keys=True) + "\n")
    print(f"wrote {len(table)} samples to {GOLDEN}", file=sys.stderr)


if __name__ == "__main__":
    main()
