"""TCP calibration with a fixed camera (seed 002): the TCP point in the flange frame and the
camera-to-base transform, from flange poses and camera observations of the TCP.

Modules: ``data`` (inputs, noise model), ``io`` (JSON/CSV), ``initial`` (seed 002's closed form and
a general linear start), ``solver`` (:func:`calibrate_tcp_camera`), ``simulate``.
"""

from plugins.calibration.tcp_camera.data import TcpCameraData, TcpNoiseModel
from plugins.calibration.tcp_camera.io import load_tcp_csv, load_tcp_json, save_tcp_csv, save_tcp_json
from plugins.calibration.tcp_camera.solver import TcpThresholds, calibrate_tcp_camera

__all__ = [
    "TcpCameraData",
    "TcpNoiseModel",
    "TcpThresholds",
    "calibrate_tcp_camera",
    "load_tcp_csv",
    "load_tcp_json",
    "save_tcp_csv",
    "save_tcp_json",
]
