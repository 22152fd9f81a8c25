"""vgr's own plugin: registers the built-in stage types through the ``vgr`` entry-point group,
exactly as a third-party package would (pyproject: ``[project.entry-points.vgr] builtin = ...``)."""

from __future__ import annotations

from engine.hookspecs import hookimpl


@hookimpl
def vgr_stage_types() -> list[type]:
    from plugins.actions.calibration_poses import CalibrationPoses
    from plugins.actions.capture import CaptureAtPose
    from plugins.actions.docking import Docking, DualDocking
    from plugins.actions.guidance import Guidance
    from plugins.actions.guidance_report import GuidanceReport
    from plugins.actions.measurement_campaign import MeasurementCampaign
    from plugins.actions.ur_robot import URRobot
    from plugins.sensors.file_camera import FileCamera
    from plugins.sensors.realsense_camera import RealSenseCamera
    from plugins.sensors.vive_tracker import ViveTracker
    from plugins.sim.stages.camera import SimCamera
    from plugins.sim.stages.evaluation import DockingEvaluator
    from plugins.sim.stages.point_tracker import SimPointTracker
    from plugins.sim.stages.robot import SimRobot
    from plugins.sim.stages.tracker import SimTracker
    from plugins.solvers.model_gap.stage import ModelGap
    from plugins.solvers.registration.stage import Matcher
    from plugins.solvers.stages.board_pose import BoardPose
    from plugins.solvers.stages.hand_eye import HandEyeCalibration
    from plugins.solvers.stages.kinematic import KinematicCalibrationStage
    from plugins.solvers.stages.result_file import CalibrationFile
    from plugins.solvers.stages.target_pose import TargetPose
    from plugins.solvers.stages.tcp import TcpCalibration
    from plugins.solvers.stages.vive import ViveDeskCalibration, ViveToDesktop
    from plugins.util.cloud_stages import CloudStats, SyntheticCloud, TransformCloud
    from plugins.util.trigger import Trigger

    sim = [SimRobot, SimCamera, SimTracker, DockingEvaluator]
    devices = [URRobot, ViveTracker, RealSenseCamera, FileCamera]
    calibration = [  # data collection in the simulated cell, solver stages, saved results
        SimPointTracker,
        CalibrationPoses,
        TargetPose,
        BoardPose,
        HandEyeCalibration,
        ViveDeskCalibration,
        ViveToDesktop,
        TcpCalibration,
        KinematicCalibrationStage,
        CalibrationFile,
    ]
    actions = [CaptureAtPose, Guidance, Docking, DualDocking, GuidanceReport]
    model_gap = [MeasurementCampaign, ModelGap]  # model-gap workflow
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
    from plugins.solvers.registration.messages import MatchResult

    return [MatchResult, GuidanceResult]


@hookimpl
def vgr_model_effects() -> list[type]:
    from plugins.solvers.model_gap.effects import FAMILIES

    return list(FAMILIES)
