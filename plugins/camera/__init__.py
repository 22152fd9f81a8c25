"""The camera: one camera type, pinhole + distortion (:mod:`plugins.camera.pinhole`'s
``CameraModel``, for calibrated, depth and simulated cameras alike; the depth projection in
:mod:`plugins.camera.depth_projection`), calibration-board descriptions
(:mod:`plugins.camera.board_spec`) and board rendering (:mod:`plugins.camera.board_render`). Used by
the simulated cell, the device adapters and calibration alike; imports none of them."""
