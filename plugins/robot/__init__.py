"""The robot model: what a calibration fits, what the simulated controller drives, what adapters check.

- ``chain.py``, ``conventions.py``, ``kinematics.py``: a serial robot as a chain of named elementary
  motions (DH, modified DH, POE), its forward kinematics and Jacobians (:class:`RobotModel`).
- ``ik.py``: numerical inverse kinematics within joint limits.
- ``model_file.py`` and ``robots/*.yaml``: model files and the shipped robots (``ur5e``, ``abb_irb120``).
- ``effects/``: the catalog of physical effects a real robot has and a nominal model lacks
  (geometric errors, compliance, backlash, encoder eccentricity, thermal drift) and, in
  ``effects/measurement.py``, those of the measuring sensor (latency, range scale and bias).
- ``with_effects.py``: a nominal model plus effects (:class:`RobotWithEffects`), with the effects'
  Jacobians used for fitting.

Nothing here knows about the simulated cell (``plugins/sim``) or the engine beyond geometry.
"""
