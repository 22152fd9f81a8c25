"""Built-in vgr stages, grouped by role (sensors, solvers, actions) plus the simulated cell (sim).

They register through the same ``vgr`` entry-point group as third-party plugins (see plugins.builtin).
"""
