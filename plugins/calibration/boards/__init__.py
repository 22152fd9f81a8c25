"""Calibration from board images: detection, camera intrinsics, the board's pose per image with
its uncertainty, hand-eye from images.

Modules: ``detect`` (OpenCV detection, sub-pixel corners, the board's own numbering),
``intrinsics`` (camera calibration with model choice, uncertainty, coverage and advice;
``camera_fit`` the OpenCV fits and their covariance),
``board_pose`` (PnP, refinement and the 6x6 covariance of ``T_cam_target``), ``handeye_images``
(hand-eye refined in pixels), ``robot_poses`` and ``recording`` (inputs), ``cli`` (``vgr calibrate
intrinsics``). The board description is plugins.camera.board_spec, the renderer of board images
with known truth plugins.camera.board_render. Units: metres and radians inside, pixels for image
quantities.
"""
