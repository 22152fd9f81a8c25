"""The simulated cell as stages: ``sim_robot`` (device), ``sim_camera`` and ``sim_tracker`` (sensors).

They offer exactly the device contracts of plugins.interfaces, plus ground truth on ``truth/``
ports and ``truth`` services (never visible to solver or action stages: the graph refuses it).
"""
