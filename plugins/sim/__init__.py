"""The simulated cell: depth camera, Vive tracker, workpieces, the robot controller's twin, the clock,
sensor-side effects and their stages. The robot model it drives is :mod:`plugins.robot`."""
