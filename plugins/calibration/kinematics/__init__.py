"""Kinematic (DH / MDH / POE) calibration of serial robots from external tool measurements.

Entry point: :func:`calibrate_kinematics` (see :mod:`.calibrate`); data: :class:`KinematicSamples`,
:func:`read_csv` / :func:`write_csv` (the plain CSV format shared with the model-gap workflow) and
:func:`read_json` / :func:`write_json` (the same columns as JSON fields); :func:`read_samples` picks
by suffix. Several measured points per pose (a ``point`` column): :mod:`.points`.
"""

from plugins.calibration.kinematics.calibrate import KinematicCalibration, calibrate_kinematics
from plugins.calibration.kinematics.data import (
    KinematicSamples,
    read_csv,
    read_json,
    read_samples,
    write_csv,
    write_json,
)
from plugins.calibration.kinematics.frames import initial_frames, initial_measurement_frame
from plugins.calibration.kinematics.identifiability import Identifiability, analyse
from plugins.calibration.kinematics.points import ToolPoints
from plugins.calibration.kinematics.problem import (
    KinematicCalibrationConfig,
    candidate_parameters,
    expected_holdout_rms,
)
from plugins.calibration.kinematics.report import format_table, plot_convergence

__all__ = [
    "Identifiability",
    "KinematicCalibration",
    "KinematicCalibrationConfig",
    "KinematicSamples",
    "ToolPoints",
    "analyse",
    "calibrate_kinematics",
    "candidate_parameters",
    "expected_holdout_rms",
    "format_table",
    "initial_frames",
    "initial_measurement_frame",
    "plot_convergence",
    "read_csv",
    "read_json",
    "read_samples",
    "write_csv",
    "write_json",
]
