"""Calibration boards: one description of a board, its detection in images, camera intrinsics,
the board's pose per image with its uncertainty, and a renderer of board images with known truth.

Modules: ``spec`` (spec strings and board files, the board frame ``target`` and its 3-D points),
``detect`` (OpenCV detection, sub-pixel corners, the board's own numbering), ``intrinsics``
(camera calibration with model choice, uncertainty, coverage and advice), ``board_pose`` (PnP,
refinement and the 6x6 covariance of ``T_cam_target``), ``render`` (synthetic board images), ``cli``
(``vgr calibrate intrinsics``). Units: metres and radians inside, pixels for image quantities.
"""

from plugins.camera.board_spec import BoardSpec, BoardSpecError, load_board, parse_board

__all__ = ["BoardSpec", "BoardSpecError", "load_board", "parse_board"]
