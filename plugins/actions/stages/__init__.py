"""The action stages: capture at a pose, iterative guidance, docking (eye-in-hand, eye-to-hand,
dual), the guidance report and the calibration-pose campaign."""
