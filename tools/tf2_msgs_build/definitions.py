"""What tf2_msgs is: its message definitions, the interface packages they use, its type supports."""

from __future__ import annotations

PACKAGE = "tf2_msgs"

# The message definitions of ros2/geometry2 tf2_msgs/msg (BSD-3-Clause): the same fields and
# constants, hence the same RIHS01 type hashes as upstream (checked against rosbags' copy).
MESSAGES: dict[str, str] = {
    "TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
    "TF2Error": (
        "uint8 NO_ERROR = 0\n"
        "uint8 LOOKUP_ERROR = 1\n"
        "uint8 CONNECTIVITY_ERROR = 2\n"
        "uint8 EXTRAPOLATION_ERROR = 3\n"
        "uint8 INVALID_ARGUMENT_ERROR = 4\n"
        "uint8 TIMEOUT_ERROR = 5\n"
        "uint8 TRANSFORM_ERROR = 6\n"
        "\n"
        "uint8 error\n"
        "string error_string\n"
    ),
}
# Interface packages the definitions depend on (transitively), all shipped as wheels.
DEPENDENCIES: tuple[str, ...] = ("geometry_msgs", "std_msgs", "builtin_interfaces")
# The C type supports rclpy uses: the dispatcher and the two it dispatches to.
TYPESUPPORTS: tuple[str, ...] = ("rosidl_typesupport_fastrtps_c", "rosidl_typesupport_introspection_c")
