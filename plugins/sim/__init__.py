"""The simulated cell: depth camera, Vive tracker, calibration boards in view, the robot
controller's twin, the clock, sensor-side effects and their stages, and the model-gap campaigns with
hidden effects (``model_gap/``). The robot model it drives is :mod:`plugins.robot`, the parts it
shows are plugins/util/workpieces.py. Only tests, benchmarks and its own stages import it."""
