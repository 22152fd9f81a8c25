"""What the self-test compares: the sample TFMessage, its DDS type name, and its CDR bytes (vs rosbags).

Everything here needs the built (or an installed) tf2_msgs; tests/ros2/test_tf2_msgs_build.py uses
these helpers too.
"""

from __future__ import annotations

from typing import Any

from .definitions import PACKAGE

EXPECTED_DDS_TYPE = "tf2_msgs::msg::dds_::TFMessage_"


def sample_message() -> Any:
    """A TFMessage with two transforms (needs the built package)."""
    from geometry_msgs.msg import TransformStamped
    from tf2_msgs.msg import TFMessage

    transforms = []
    for i, child in enumerate(("vgr_tool", "vgr_camera")):
        t = TransformStamped()
        t.header.stamp.sec = 1_700_000_000 + i
        t.header.stamp.nanosec = 123_456_789
        t.header.frame_id = "base"
        t.child_frame_id = child
        t.transform.translation.x = 0.5 + i
        t.transform.translation.y = -0.25
        t.transform.translation.z = 1.0 / 3.0
        t.transform.rotation.z = 0.7071067811865476
        t.transform.rotation.w = 0.7071067811865476
        transforms.append(t)
    return TFMessage(transforms=transforms)


def dds_type_name() -> str:
    """The DDS type name rmw_fastrtps registers for TFMessage (namespace::dds_::Name_)."""
    import ctypes

    lib = ctypes.CDLL(f"lib{PACKAGE}__rosidl_typesupport_fastrtps_c.so")
    handle = getattr(lib, f"rosidl_typesupport_fastrtps_c__get_message_type_support_handle__{PACKAGE}__msg__TFMessage")
    handle.restype = ctypes.POINTER(ctypes.c_void_p * 2)  # {typesupport_identifier, data}
    data = handle().contents[1]
    # message_type_support_callbacks_t starts with message_namespace_, message_name_
    names = ctypes.cast(data, ctypes.POINTER(ctypes.c_char_p * 2)).contents
    namespace, name = ((n or b"").decode() for n in names)
    return f"{namespace}::dds_::{name}_" if namespace else f"dds_::{name}_"


def tfmessage_padding(message: Any) -> frozenset[int]:
    """Byte offsets (in the serialized buffer, CDR header included) of TFMessage's alignment padding.

    CDR leaves the value of padding bytes unspecified; Fast CDR does not write them
    (they hold whatever the buffer held), rosbags writes zeros.  Comparisons skip them.
    """
    header = 4
    pos = 0
    padding: set[int] = set()

    def align(n: int) -> None:
        nonlocal pos
        while pos % n:
            padding.add(header + pos)
            pos += 1

    pos += 4  # sequence length
    for t in message.transforms:
        align(4)
        pos += 8  # stamp.sec, stamp.nanosec
        for text in (t.header.frame_id, t.child_frame_id):
            align(4)
            pos += 4 + len(text.encode()) + 1
        align(8)
        pos += 7 * 8  # translation xyz, rotation xyzw
    return frozenset(padding)


def equal_except(a: bytes, b: bytes, skip: frozenset[int]) -> bool:
    """Whether two buffers have the same length and agree outside the offsets in skip."""
    return len(a) == len(b) and all(x == y for i, (x, y) in enumerate(zip(a, b, strict=True)) if i not in skip)


def rosbags_bytes(message: Any) -> bytes | None:
    """rosbags' CDR serialization of the same message, or None if rosbags is absent."""
    store = rosbags_store()
    if store is None:
        return None
    rb = store.types
    transforms = [
        rb["geometry_msgs/msg/TransformStamped"](
            header=rb["std_msgs/msg/Header"](
                stamp=rb["builtin_interfaces/msg/Time"](sec=t.header.stamp.sec, nanosec=t.header.stamp.nanosec),
                frame_id=t.header.frame_id,
            ),
            child_frame_id=t.child_frame_id,
            transform=rb["geometry_msgs/msg/Transform"](
                translation=rb["geometry_msgs/msg/Vector3"](
                    x=t.transform.translation.x, y=t.transform.translation.y, z=t.transform.translation.z
                ),
                rotation=rb["geometry_msgs/msg/Quaternion"](
                    x=t.transform.rotation.x,
                    y=t.transform.rotation.y,
                    z=t.transform.rotation.z,
                    w=t.transform.rotation.w,
                ),
            ),
        )
        for t in message.transforms
    ]
    return bytes(store.serialize_cdr(rb["tf2_msgs/msg/TFMessage"](transforms=transforms), "tf2_msgs/msg/TFMessage"))


def rosbags_store() -> Any:
    """rosbags' ROS 2 Kilted type store, or None if rosbags is not installed."""
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        return None
    return get_typestore(Stores.ROS2_KILTED if hasattr(Stores, "ROS2_KILTED") else Stores.LATEST)
