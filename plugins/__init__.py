"""Built-in vgr stages by role (sensors, solvers, actions), the robot model (robot) and the simulated cell (sim).

They register through the same ``vgr`` entry-point group as third-party plugins (see plugins.builtin).
"""
