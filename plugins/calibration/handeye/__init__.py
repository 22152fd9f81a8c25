"""Hand-eye (AX=XB) and robot-world (AX=ZB) calibration: library API (no engine dependency).

Entry points: :func:`calibrate_hand_eye`, :func:`calibrate_robot_world` (return
``plugins.calibration.result.CalibrationResult``; the set-up is found from the data unless
given; each sample's own camera covariance with ``camera_covariances=``), the loaders
:func:`load_pose_pairs` (JSON, CSV, OpenCV YAML; optional per-sample ``camera_cov``), the Cramér–Rao
bound :func:`crlb_covariance` and the report :func:`format_report`.
See docs/handeye.md for the models, conventions and file formats.
"""

from plugins.calibration.handeye.closed_form import CLOSED_FORM_METHODS, closed_form
from plugins.calibration.handeye.crlb import crlb_covariance, rms_bounds
from plugins.calibration.handeye.degeneracy import MotionThresholds, analyse_motions
from plugins.calibration.handeye.io import PoseSamples, load_pose_pairs, write_pose_pairs_json, write_pose_pairs_yaml
from plugins.calibration.handeye.noise import DEFAULT_PRIOR, NoiseModel, PoseNoise
from plugins.calibration.handeye.problem import SETUPS, Setup
from plugins.calibration.handeye.report import format_report
from plugins.calibration.handeye.setup_choice import SETUP_TEST_LEVEL
from plugins.calibration.handeye.solver import (
    RESIDUAL_NAMES,
    AccuracyTargets,
    SetupOrAuto,
    calibrate_hand_eye,
    calibrate_robot_world,
)
from plugins.calibration.handeye.validation import HandEyeInputError

__all__ = [
    "CLOSED_FORM_METHODS",
    "DEFAULT_PRIOR",
    "RESIDUAL_NAMES",
    "SETUPS",
    "SETUP_TEST_LEVEL",
    "AccuracyTargets",
    "HandEyeInputError",
    "MotionThresholds",
    "NoiseModel",
    "PoseNoise",
    "PoseSamples",
    "Setup",
    "SetupOrAuto",
    "analyse_motions",
    "calibrate_hand_eye",
    "calibrate_robot_world",
    "closed_form",
    "crlb_covariance",
    "format_report",
    "load_pose_pairs",
    "rms_bounds",
    "write_pose_pairs_json",
    "write_pose_pairs_yaml",
]
