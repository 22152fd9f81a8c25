"""Calibration solver stages: hand-eye / robot-world, Vive desk (+ real-time conversion), TCP by
camera, kinematic; and a source that publishes a saved calibration result.

Each solver collects its samples from the bus, calibrates with its library when a ``solve`` trigger
arrives or when its inputs end, publishes the CalibrationResult and, only when the verdict is
usable, the calibrated transforms (:mod:`.base`).
"""
