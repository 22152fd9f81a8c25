"""Actions: robot moves, the guidance loop and its maths, docking, calibration pose campaigns,
``vgr teach``. The stages are in ``stages/``; the UR adapter is in plugins.devices."""
