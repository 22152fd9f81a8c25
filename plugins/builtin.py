"""vgr's own plugin: registers the built-in stage types through the ``vgr`` entry-point group,
exactly as a third-party package would (pyproject: ``[project.entry-points.vgr] builtin = ...``)."""

from __future__ import annotations

from engine.hookspecs import CellGateway, CliVerb, hookimpl


@hookimpl
def vgr_stage_types() -> list[type]:
    from plugins.actions.stages.calibration_poses import CalibrationPoses
    from plugins.actions.stages.capture import CaptureAtPose
    from plugins.actions.stages.cell_locator import CellLocator
    from plugins.actions.stages.docking import Docking, DualDocking
    from plugins.actions.stages.guidance import Guidance
    from plugins.actions.stages.guidance_report import GuidanceReport
    from plugins.calibration.stages.board_pose import BoardPose
    from plugins.calibration.stages.hand_eye import HandEyeCalibration
    from plugins.calibration.stages.hand_eye_board import HandEyeBoardCalibration
    from plugins.calibration.stages.kinematic import KinematicCalibrationStage
    from plugins.calibration.stages.result_file import CalibrationFile
    from plugins.calibration.stages.target_pose import TargetPose
    from plugins.calibration.stages.tcp import TcpCalibration
    from plugins.calibration.stages.vive import ViveDeskCalibration, ViveToDesktop
    from plugins.devices.stages.file_camera import FileCamera
    from plugins.devices.stages.realsense_camera import RealSenseCamera
    from plugins.devices.stages.ur_robot import URRobot
    from plugins.devices.stages.vive_tracker import ViveTracker
    from plugins.model_gap.stages.camera_gap import CameraGap
    from plugins.model_gap.stages.depth_gap import DepthGap
    from plugins.model_gap.stages.measurement_campaign import MeasurementCampaign
    from plugins.model_gap.stages.model_gap import ModelGap
    from plugins.registration.stages.matcher import Matcher
    from plugins.ros2.camera_stage import Ros2Camera
    from plugins.ros2.publisher_stage import Ros2Publish
    from plugins.ros2.subscriber_stage import Ros2Subscribe
    from plugins.sim.stages.calibration_evaluation import CalibrationEvaluator
    from plugins.sim.stages.camera import SimCamera
    from plugins.sim.stages.evaluation import DockingEvaluator
    from plugins.sim.stages.point_tracker import SimPointTracker
    from plugins.sim.stages.robot import SimRobot
    from plugins.sim.stages.tracker import SimTracker
    from plugins.util.stages.clouds import CloudStats, SyntheticCloud, TransformCloud
    from plugins.util.stages.trigger import Trigger

    sim = [SimRobot, SimCamera, SimTracker, DockingEvaluator, CalibrationEvaluator]
    devices = [URRobot, ViveTracker, RealSenseCamera, FileCamera, Ros2Camera, Ros2Publish, Ros2Subscribe]
    calibration = [  # data collection in the simulated cell, solver stages, saved results
        SimPointTracker,
        CalibrationPoses,
        TargetPose,
        BoardPose,
        HandEyeCalibration,
        HandEyeBoardCalibration,
        ViveDeskCalibration,
        ViveToDesktop,
        TcpCalibration,
        KinematicCalibrationStage,
        CalibrationFile,
    ]
    actions = [CaptureAtPose, Guidance, Docking, DualDocking, GuidanceReport, CellLocator]
    model_gap = [MeasurementCampaign, ModelGap, CameraGap, DepthGap]  # model-gap workflow (robot; camera; depth)
    return [
        SyntheticCloud,
        TransformCloud,
        CloudStats,
        Trigger,
        *sim,
        *actions,
        Matcher,
        *devices,
        *calibration,
        *model_gap,
    ]


@hookimpl
def vgr_message_types() -> list[type]:
    from plugins.actions.messages import GuidanceResult
    from plugins.registration.messages import MatchResult

    return [MatchResult, GuidanceResult]


@hookimpl
def vgr_model_effects() -> list[type]:
    from plugins.model_gap.effects import FAMILIES

    return list(FAMILIES)


@hookimpl
def vgr_cli_verbs() -> list[CliVerb]:
    return [
        CliVerb("template", "make or show a matcher template", "plugins.registration.cli"),
        CliVerb(
            "calibrate",
            "hand-eye, robot-world, Vive desk, TCP, kinematic or camera-intrinsics calibration",
            "plugins.calibration.cli",
        ),
        CliVerb(
            "teach", "store the robot's current pose as the recipe's photo or install pose", "plugins.actions.teach_cli"
        ),
        CliVerb(
            "gap", "compare a robot model with measurements, name the missing effect, add it", "plugins.model_gap.cli"
        ),
        CliVerb("bag", "import a rosbag2 as a vgr recording, export a recording as a rosbag2", "plugins.ros2.bag"),
    ]


@hookimpl
def vgr_cell_gateways() -> list[CellGateway]:
    return [CellGateway("tcp", "plugins.actions.cell.tcp_gateway"), CellGateway("ros2", "plugins.ros2.gateway")]
