"""Solvers: point-cloud registration, hand-eye, Vive desk, TCP and kinematic calibration, the
model-gap fit; each folder a library, ``stages/`` the recipe stages that call them."""
