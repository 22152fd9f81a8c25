"""The camera: pinhole + distortion models (:mod:`plugins.camera.pinhole`, the depth projection in
:mod:`plugins.camera.depth_projection`), calibration-board descriptions
(:mod:`plugins.camera.board_spec`) and board rendering (:mod:`plugins.camera.board_render`). Used by
the simulated cell, the device adapters and calibration alike; imports none of them."""
