"""Built-in vgr stages and the libraries behind them, one package per concern: the robot model
(robot), the camera model and boards (camera), device adapters (devices), point-cloud registration
(registration), calibration, the model-gap workflow (model_gap), robot actions (actions), generic
stages and the demo parts (util) and the simulated cell (sim).

They register through the same ``vgr`` entry-point group as third-party plugins (see plugins.builtin).
"""
