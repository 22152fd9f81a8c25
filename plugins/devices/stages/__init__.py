"""The device stages: ``ur_robot``, ``realsense_camera``, ``vive_tracker``, ``file_camera``."""
