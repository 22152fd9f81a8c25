"""Calibration: boards and intrinsics (``boards/``), hand-eye (``handeye/``), the Vive desk and
tracker-to-TCP (``vive_desk/``), TCP from camera views (``tcp_camera/``), kinematic DH/POE
calibration (``kinematics/``), the shared pose least squares (``pose_lsq/``), input files, results
and reports, the ``vgr calibrate`` verbs (:mod:`plugins.calibration.cli`) and the recipe stages
(``stages/``). Units: metres and radians inside; mm and degrees in reports."""
