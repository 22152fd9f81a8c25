"""Poses, transforms and joint states: ``geometry_msgs/PoseStamped``,
``geometry_msgs/PoseWithCovarianceStamped``, ``geometry_msgs/TransformStamped``,
``tf2_msgs/TFMessage`` (``/tf``, ``/tf_static``) and ``sensor_msgs/JointState`` <-> vgr.

Poses and transforms are position + unit quaternion (x, y, z, w) on both sides; vgr holds a 4x4
``T`` and sends the quaternion. So that a pose crosses unchanged, bit for bit, a converted message
keeps the quaternion it came with: ROS -> vgr attaches vgr's wire form built from the ROS numbers
(engine.messages ``WIRE_CACHE``, which the codec writes as it is), and vgr -> ROS takes the quaternion
of the message's wire form when it has one (a received or replayed message), else of ``T``.
A quaternion that is not of unit length (an unset, all-zero one) is refused, naming the field.

TFMessage: each ``TransformStamped`` is one vgr :class:`~engine.messages.Transform` (``frame_id`` =
the parent, ``child_frame_id``, ``T`` = T_parent_child, its own stamp); the FrameTransforms' stamp
is the first transform's (as vgr's own decoding gives it). JointState: ``name``, ``position``,
``velocity``, ``effort``; an empty velocity / effort array is vgr's None, and arrays of another
length than ``name`` are refused.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from engine import transforms as tf
from engine.messages import (
    WIRE_CACHE,
    FrameTransforms,
    JointState,
    Message,
    PoseStamped,
    PoseWithCovarianceStamped,
    Transform,
)
from engine.messages.mapping import pose_from_parts
from plugins.ros2.convert_common import Ctx, ros_class, stamp_ns

# --------------------------------------------------------------------------- quaternions


def _T(p: Any, q: Any, cx: Ctx, field: str) -> np.ndarray:
    try:
        return pose_from_parts(p, q)
    except ValueError as exc:
        raise cx.error(field, str(exc)) from None


def _set_parts(position_pb: Any, orientation_pb: Any, p: Any, q: Any) -> None:
    position_pb.x, position_pb.y, position_pb.z = float(p.x), float(p.y), float(p.z)
    orientation_pb.x, orientation_pb.y, orientation_pb.z, orientation_pb.w = (
        float(q.x), float(q.y), float(q.z), float(q.w)
    )  # fmt: skip


def _keep_wire(msg: Message, fill: Any) -> Message:
    """*msg* with its wire form: vgr's generated protobuf, whose poses *fill(pb)* sets to the ROS numbers."""
    pb, bulk = msg.to_proto()
    fill(pb)
    msg.__dict__[WIRE_CACHE] = (pb, bulk)
    return msg


def _wire(msg: Message) -> Any:
    wire = msg.__dict__.get(WIRE_CACHE)
    return None if wire is None else wire[0]


def _ros_pose(T: np.ndarray, wire_pose: Any, *, point: str = "Point") -> tuple[Any, Any]:
    """(position, orientation) ROS dataclasses of *T*, the quaternion of *wire_pose* when given."""
    T = np.asarray(T, dtype=float)
    quat: tuple[float, ...]
    if wire_pose is not None:
        q = wire_pose[1]
        quat = (q.x, q.y, q.z, q.w)
    else:
        quat = tuple(float(v) for v in tf.quat_xyzw_from_R(T[:3, :3]))
    P = ros_class(f"geometry_msgs/msg/{point}")
    Q = ros_class("geometry_msgs/msg/Quaternion")
    x, y, z = (float(v) for v in T[:3, 3])
    return P(x=x, y=y, z=z), Q(x=float(quat[0]), y=float(quat[1]), z=float(quat[2]), w=float(quat[3]))


# --------------------------------------------------------------------------- poses


def pose_from_ros(msg: Any, cx: Ctx) -> PoseStamped:
    pose = msg.pose
    T = _T(pose.position, pose.orientation, cx, "pose.orientation")
    m = PoseStamped(stamp_ns=stamp_ns(msg.header.stamp), frame_id=cx.to_vgr(str(msg.header.frame_id)), T=T)
    return _keep_wire(m, lambda pb: _set_parts(pb.pose.position, pb.pose.orientation, pose.position, pose.orientation))  # type: ignore[return-value]


def pose_to_ros(m: PoseStamped, cx: Ctx) -> Any:
    pb = _wire(m)
    p, q = _ros_pose(m.T, None if pb is None else (pb.pose.position, pb.pose.orientation))
    return ros_class("geometry_msgs/msg/PoseStamped")(
        header=cx.header(m.stamp_ns, m.frame_id), pose=ros_class("geometry_msgs/msg/Pose")(position=p, orientation=q)
    )


def pose_cov_from_ros(msg: Any, cx: Ctx) -> PoseWithCovarianceStamped:
    pose = msg.pose.pose
    T = _T(pose.position, pose.orientation, cx, "pose.pose.orientation")
    cov = np.asarray(msg.pose.covariance, dtype=float)
    if cov.size != 36:
        raise cx.error("pose.covariance", f"has {cov.size} values, not 36")
    m = PoseWithCovarianceStamped(
        stamp_ns=stamp_ns(msg.header.stamp),
        frame_id=cx.to_vgr(str(msg.header.frame_id)),
        T=T,
        covariance=cov.reshape(6, 6).copy(),
    )
    return _keep_wire(m, lambda pb: _set_parts(pb.pose.position, pb.pose.orientation, pose.position, pose.orientation))  # type: ignore[return-value]


def pose_cov_to_ros(m: PoseWithCovarianceStamped, cx: Ctx) -> Any:
    pb = _wire(m)
    p, q = _ros_pose(m.T, None if pb is None else (pb.pose.position, pb.pose.orientation))
    pose = ros_class("geometry_msgs/msg/Pose")(position=p, orientation=q)
    cov = np.asarray(m.covariance, dtype=np.float64).reshape(-1).copy()
    return ros_class("geometry_msgs/msg/PoseWithCovarianceStamped")(
        header=cx.header(m.stamp_ns, m.frame_id),
        pose=ros_class("geometry_msgs/msg/PoseWithCovariance")(pose=pose, covariance=cov),
    )


# --------------------------------------------------------------------------- transforms


def _transform(t: Any, cx: Ctx, where: str) -> Transform:
    tr = t.transform
    return Transform(
        stamp_ns=stamp_ns(t.header.stamp),
        frame_id=cx.to_vgr(str(t.header.frame_id), f"{where}header.frame_id"),
        child_frame_id=cx.to_vgr(str(t.child_frame_id), f"{where}child_frame_id"),
        T=_T(tr.translation, tr.rotation, cx, f"{where}transform.rotation"),
    )


def _ros_transform(t: Transform, wire: Any, cx: Ctx, where: str) -> Any:
    p, q = _ros_pose(t.T, None if wire is None else (wire.translation, wire.rotation), point="Vector3")
    return ros_class("geometry_msgs/msg/TransformStamped")(
        header=cx.header(t.stamp_ns, t.frame_id),
        child_frame_id=cx.to_ros(t.child_frame_id, f"{where}child_frame_id"),
        transform=ros_class("geometry_msgs/msg/Transform")(translation=p, rotation=q),
    )


def transform_from_ros(msg: Any, cx: Ctx) -> Transform:
    m = _transform(msg, cx, "")
    tr = msg.transform
    return _keep_wire(m, lambda pb: _set_parts(pb.translation, pb.rotation, tr.translation, tr.rotation))  # type: ignore[return-value]


def transform_to_ros(m: Transform, cx: Ctx) -> Any:
    return _ros_transform(m, _wire(m), cx, "")


def tf_from_ros(msg: Any, cx: Ctx) -> FrameTransforms:
    ts = [_transform(t, cx, f"transforms[{i}].") for i, t in enumerate(msg.transforms)]
    m = FrameTransforms(stamp_ns=ts[0].stamp_ns if ts else 0, transforms=ts)

    def fill(pb: Any) -> None:
        for out, t in zip(pb.transforms, msg.transforms, strict=True):
            _set_parts(out.translation, out.rotation, t.transform.translation, t.transform.rotation)

    return _keep_wire(m, fill)  # type: ignore[return-value]


def tf_to_ros(m: FrameTransforms, cx: Ctx) -> Any:
    pb = _wire(m)
    wires = list(pb.transforms) if pb is not None and len(pb.transforms) == len(m.transforms) else None
    out = []
    for i, t in enumerate(m.transforms):
        own = _wire(t)
        w = own if own is not None else (wires[i] if wires is not None else None)
        out.append(_ros_transform(t, w, cx, f"transforms[{i}]."))
    return ros_class("tf2_msgs/msg/TFMessage")(transforms=out)


# --------------------------------------------------------------------------- joint states


def joints_from_ros(msg: Any, cx: Ctx) -> JointState:
    names = [str(n) for n in msg.name]
    pos = np.asarray(msg.position, dtype=np.float64)
    vel = np.asarray(msg.velocity, dtype=np.float64)
    eff = np.asarray(msg.effort, dtype=np.float64)
    if names and len(pos) != len(names):
        raise cx.error("position", f"has {len(pos)} values for {len(names)} names")
    for field, arr in (("velocity", vel), ("effort", eff)):
        if len(arr) and len(arr) != len(pos):
            raise cx.error(field, f"has {len(arr)} values for {len(pos)} positions (empty or as many)")
    return JointState(
        stamp_ns=stamp_ns(msg.header.stamp),
        frame_id=cx.to_vgr(str(msg.header.frame_id)),
        names=names,
        positions=pos.copy(),
        velocities=vel.copy() if len(vel) else None,
        efforts=eff.copy() if len(eff) else None,
    )


def joints_to_ros(m: JointState, cx: Ctx) -> Any:
    pos = np.asarray(m.positions, dtype=np.float64).reshape(-1)
    names = list(m.names) or [f"joint{i + 1}" for i in range(len(pos))]
    if len(names) != len(pos):
        raise cx.error("name", f"{len(names)} names for {len(pos)} positions")

    def arr(a: np.ndarray | None) -> np.ndarray:
        return np.zeros(0) if a is None else np.asarray(a, dtype=np.float64).reshape(-1).copy()

    return ros_class("sensor_msgs/msg/JointState")(
        header=cx.header(m.stamp_ns, m.frame_id), name=names, position=pos.copy(), velocity=arr(m.velocities),
        effort=arr(m.efforts),
    )  # fmt: skip
