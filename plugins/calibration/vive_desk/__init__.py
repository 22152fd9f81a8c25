"""Vive desk calibration (seed 001): T_base_desktop and T_tracker_tcp from fixture contacts,
and the real-time conversion T_desktop_tcp = inv(T_base_desktop) T_base_tracker T_tracker_tcp.

Modules: ``data`` (inputs, noise model, prior), ``io`` (JSON/CSV), ``checks`` (input checks,
seed 001 pose-consistency bands), ``initial`` (seed step 1, literal and exact), ``model``
(residuals, analytic Jacobian), ``solver`` (:func:`calibrate_vive_desk`), ``realtime``
(:class:`DesktopTcpConverter`), ``seed_baseline`` (the seed's L-BFGS-B), ``simulate``.
"""

from plugins.calibration.vive_desk.checks import ViveThresholds
from plugins.calibration.vive_desk.data import TrackerTcpPrior, ViveDeskData, ViveNoiseModel
from plugins.calibration.vive_desk.io import load_vive_csv, load_vive_json, save_vive_csv, save_vive_json
from plugins.calibration.vive_desk.realtime import DesktopTcpConverter, DesktopTcpPose, desktop_tcp
from plugins.calibration.vive_desk.solver import calibrate_vive_desk

__all__ = [
    "DesktopTcpConverter",
    "DesktopTcpPose",
    "TrackerTcpPrior",
    "ViveDeskData",
    "ViveNoiseModel",
    "ViveThresholds",
    "calibrate_vive_desk",
    "desktop_tcp",
    "load_vive_csv",
    "load_vive_json",
    "save_vive_csv",
    "save_vive_json",
]
