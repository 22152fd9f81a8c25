"""vgr in a ROS 2 cell: conversions between ROS 2 standard messages and vgr's, bags, and the bridge.

* ``convert`` (with ``convert_common``, ``convert_cloud``, ``convert_image``, ``convert_geometry``):
  ROS 2 messages (the ``rosbags`` library's typestore dataclasses, CDR bytes as rclpy delivers
  them) <-> vgr messages, done once for the bridge stages and the bags (docs/ros2.md);
* ``bag`` (with ``bag_export``, ``bag_import``): ``vgr bag import`` / ``vgr bag export``, rosbag2
  <-> vgr recordings;
* the live rclpy bridge: the stages (``ros2_camera``, ...), the shared node, QoS profiles.

Nothing here is imported by vgr unless a ROS 2 feature is used: ``rosbags`` (and rclpy) come with
the optional extra ``pip install vgr[ros2]`` and are imported lazily; without it a ROS 2 feature
fails with an error saying so, and the rest of vgr is unaffected.
"""
