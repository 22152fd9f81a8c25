"""vgr's own plugin: registers the built-in stage types through the ``vgr`` entry-point group,
exactly as a third-party package would (pyproject: ``[project.entry-points.vgr] builtin = ...``)."""

from __future__ import annotations

from engine.hookspecs import hookimpl


@hookimpl
def vgr_stage_types() -> list[type]:
    from plugins.actions.capture import CaptureAtPose
    from plugins.actions.measurement_campaign import MeasurementCampaign
    from plugins.sim.stages.camera import SimCamera
    from plugins.sim.stages.robot import SimRobot
    from plugins.sim.stages.tracker import SimTracker
    from plugins.solvers.model_gap.stage import ModelGap
    from plugins.util.cloud_stages import CloudStats, SyntheticCloud, TransformCloud
    from plugins.util.trigger import Trigger

    return [
        SyntheticCloud,
        TransformCloud,
        CloudStats,
        Trigger,
        SimRobot,
        SimCamera,
        SimTracker,
        CaptureAtPose,
        MeasurementCampaign,
        ModelGap,
    ]


@hookimpl
def vgr_model_effects() -> list[type]:
    from plugins.solvers.model_gap.effects import FAMILIES

    return list(FAMILIES)
