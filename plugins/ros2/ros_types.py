"""The rclpy message class of a ROS 2 type name (``sensor_msgs/msg/PointCloud2``), imported when a
bridge stage or the gateway first needs it, with an error that names the missing package."""

from __future__ import annotations

import importlib
from typing import Any

from plugins.util.sdk import MissingSDKError

#: the ROS 2 packages a type's module comes from, and where a user finds them
_PACKAGES = {
    "tf2_msgs": "ros-tf2-msgs (or a ROS 2 install; tools/build_tf2_msgs.py builds it from its definition)",
}


def ros_class(msgtype: str) -> Any:
    """The rclpy class of *msgtype* (``pkg/msg/Name``); MissingSDKError when its package is absent."""
    parts = msgtype.split("/")
    if len(parts) != 3 or parts[1] not in ("msg", "srv"):
        raise ValueError(f"ROS 2 type {msgtype!r}: write package/msg/Name, e.g. sensor_msgs/msg/PointCloud2")
    package, kind, name = parts
    try:
        module = importlib.import_module(f"{package}.{kind}")
    except ImportError as exc:
        where = _PACKAGES.get(package, f"ros-{package.replace('_', '-')}")
        raise MissingSDKError(
            f"ROS 2 type {msgtype!r} needs the Python package {package!r}, which cannot be imported ({exc}); "
            f"install {where}"
        ) from exc
    try:
        return getattr(module, name)
    except AttributeError:
        raise ValueError(f"ROS 2 package {package!r} has no {kind} type {name!r}") from None
