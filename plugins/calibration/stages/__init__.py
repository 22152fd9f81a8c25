"""Calibration solver stages: hand-eye / robot-world, Vive desk (+ real-time conversion), TCP by
camera, kinematic; the camera observations they take (``target_pose``: a known part registered in
a capture, ``board_pose``: a calibration board in an image, with its covariance); and a source that
publishes a saved calibration result.

Each solver collects its samples from the bus, calibrates with its library when a ``solve`` trigger
arrives or when its inputs end, publishes the CalibrationResult and, only when the verdict is
usable, the calibrated transforms (:mod:`.base`).
"""
