"""Actions: robot moves, the guidance loop, docking, calibration pose campaigns and the UR adapter."""
