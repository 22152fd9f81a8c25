"""Device contracts: the ports and services every robot, depth camera and tracker stage offers.

A simulated twin and a real adapter of the same device class declare exactly these, so a recipe
switches between the simulated cell and the real one by changing ``type:`` and parameters only.

Robot (role ``device``)
    services ``move`` (RobotCommand -> RobotReply: ``move_j`` with joints, ``move_l`` with
    ``T`` = T_base_tcp, ``stop``; each ``command_id`` executes at most once, a repeat returns the first
    reply with ``duplicate`` set; a refused command moves nothing and says why in ``error``) and
    ``state`` (Request -> RobotReply with the current joints and T_base_tcp; no motion).
    Outputs ``joint_state`` (JointState), ``tcp_pose`` (PoseStamped, T_base_tcp in ``base``) and
    ``frames`` (FrameTransforms for the 3D view), published after every command.
Depth camera (role ``sensor``)
    service ``capture`` (Request -> PointCloud in the camera frame ``camera``, metres; args may carry
    ``{"timeout_s": ...}``); outputs ``cloud`` (the same cloud, unless ``publish_cloud: false``; every
    n-th point of it with ``cloud_decimate: n``),
    ``depth`` (Image 32FC1, metres, NaN invalid) and ``camera_info`` (CameraInfo).
Tracker (role ``sensor``)
    output ``pose`` (TrackerPose, T_lighthouse_tracker) at the device rate; service ``sample``
    (Request -> TrackerPose: the latest pose).

Simulated stages may also publish ground truth on ports named ``truth/...``; the graph refuses to
wire a ``truth/`` port into any stage that is not a sensor, device or sink (solvers never see it).
"""

from __future__ import annotations

from collections.abc import Mapping

from engine.messages import (
    CameraInfo,
    FrameTransforms,
    Image,
    JointState,
    Message,
    PointCloud,
    PoseStamped,
    Request,
    RobotCommand,
    RobotReply,
    TrackerPose,
)
from engine.stage import ServiceSpec

ROBOT_SERVICES: Mapping[str, ServiceSpec] = {
    "move": ServiceSpec(RobotCommand, RobotReply, "move_j / move_l / stop; each command_id executes at most once"),
    "state": ServiceSpec(Request, RobotReply, "current joints and T_base_tcp, no motion"),
}
ROBOT_OUTPUTS: Mapping[str, type[Message]] = {
    "joint_state": JointState,
    "tcp_pose": PoseStamped,
    "frames": FrameTransforms,
}
CAMERA_SERVICES: Mapping[str, ServiceSpec] = {
    "capture": ServiceSpec(Request, PointCloud, "capture now; the cloud in the camera frame"),
}
CAMERA_OUTPUTS: Mapping[str, type[Message]] = {"cloud": PointCloud, "depth": Image, "camera_info": CameraInfo}
TRACKER_SERVICES: Mapping[str, ServiceSpec] = {
    "sample": ServiceSpec(Request, TrackerPose, "the latest tracker pose"),
}
TRACKER_OUTPUTS: Mapping[str, type[Message]] = {"pose": TrackerPose}

# What a stage that *uses* a device declares in its ``uses`` (client side of the contracts).
ROBOT_MOVE = ServiceSpec(RobotCommand, RobotReply)
ROBOT_STATE = ServiceSpec(Request, RobotReply)
CAMERA_CAPTURE = ServiceSpec(Request, PointCloud)
TRACKER_SAMPLE = ServiceSpec(Request, TrackerPose)
