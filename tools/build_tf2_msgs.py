#!/usr/bin/env python3
"""Build the ROS 2 ``tf2_msgs`` message package into this Python environment.

vgr publishes and receives ``/tf`` and ``/tf_static`` (``tf2_msgs/msg/TFMessage``)
with real rclpy, but the package index that provides the ROS 2 wheels
(``ros-rclpy``, ``ros-geometry-msgs``, ...) has no ``ros-tf2-msgs``.  This script
generates the package from its two message definitions with the installed
rosidl generators and compiles it with gcc/g++, exactly the artefacts that
``rosidl_generate_interfaces()`` would produce for rclpy:

* ``<prefix>/lib/libtf2_msgs__rosidl_generator_c.so``, ``..._typesupport_c.so``,
  ``..._typesupport_fastrtps_c.so``, ``..._typesupport_introspection_c.so``,
  ``..._generator_py.so``
* ``site-packages/tf2_msgs/`` (``msg/*.py`` and the
  ``tf2_msgs_s__rosidl_typesupport_*.so`` extension modules)
* headers under ``<prefix>/include/tf2_msgs``, the ``.msg``/``.idl``/``.json``
  definitions under ``<prefix>/share/tf2_msgs``, the ament index markers, and a
  ``ros_tf2_msgs-*.dist-info`` so that ``pip uninstall ros-tf2-msgs`` removes it.

The DDS type is ``tf2_msgs::msg::dds_::TFMessage_`` with the standard CDR
layout, so it interoperates with a stock ROS 2 ``tf2_msgs``.

It is idempotent: when ``tf2_msgs`` already imports with working type support
(a sourced ROS 2 install, or an earlier run) it does nothing.  After a build it
verifies a publish/subscribe round trip between two processes over Fast DDS on
loopback (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, ``ROS_DOMAIN_ID`` 91 by
default, 10 s bound), including a ``raw=True`` subscription whose bytes are
compared with ``rclpy.serialization`` and, when importable, with rosbags.

Usage (from the venv)::

    .venv/bin/python tools/build_tf2_msgs.py            # build if missing, then verify
    .venv/bin/python tools/build_tf2_msgs.py --verify   # only the round-trip check
    .venv/bin/python tools/build_tf2_msgs.py --force    # rebuild even if present
    .venv/bin/python tools/build_tf2_msgs.py --uninstall

Needs gcc and g++ (Debian: ``apt-get install -y build-essential``), the Python
headers (``Python.h``; Debian's own python3.11: ``python3.11-dev``), numpy, and the
``ros-rosidl-*`` generator wheels that ``ros-rclpy`` pulls in.

Exit codes: 0 built and verified, or nothing to do; 1 the built package does not import or the
round trip failed; 2 a prerequisite is missing or a build step failed (the message says which).

This script only parses its command line; the steps live in ``tools/tf2_msgs_build/`` (one
module per step, listed in its ``__init__``).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
from collections.abc import Sequence
from pathlib import Path

# tools/ is not a package: make tf2_msgs_build (next to this script) importable however the script is run.
_HERE = str(Path(__file__).resolve().parent)
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)

from tf2_msgs_build.build import build_and_install  # noqa: E402
from tf2_msgs_build.common import BuildError, Layout, log  # noqa: E402
from tf2_msgs_build.install import uninstall  # noqa: E402
from tf2_msgs_build.selftest import run_publisher, run_subscriber  # noqa: E402
from tf2_msgs_build.verify import (  # noqa: E402
    DEFAULT_DOMAIN_ID,
    ROUND_TRIP_TIMEOUT_S,
    SELFTEST_TOPIC,
    tf2_msgs_status,
    verify,
)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line ``argv`` (default: ``sys.argv[1:]``); return the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    action = parser.add_mutually_exclusive_group()
    action.add_argument("--force", action="store_true", help="rebuild even if tf2_msgs already imports")
    action.add_argument("--verify", action="store_true", help="only run the round-trip check")
    action.add_argument("--uninstall", action="store_true", help="remove a tf2_msgs this script installed")
    action.add_argument("--_publisher", action="store_true", help=argparse.SUPPRESS)
    action.add_argument("--_subscriber", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--no-verify", action="store_true", help="skip the round trip after building")
    parser.add_argument("--keep-build", action="store_true", help="keep the temporary build folder")
    parser.add_argument(
        "--domain-id", type=int, default=int(os.environ.get("VGR_TF2_SELFTEST_DOMAIN_ID", DEFAULT_DOMAIN_ID))
    )
    parser.add_argument("--topic", default=SELFTEST_TOPIC, help=argparse.SUPPRESS)
    parser.add_argument("--timeout", type=float, default=ROUND_TRIP_TIMEOUT_S, help="round-trip wait bound, s")
    args = parser.parse_args(argv)

    if args._publisher:
        return run_publisher(args.topic, args.timeout)
    if args._subscriber:
        return run_subscriber(args.topic, args.timeout)

    layout = Layout.current()
    if args.uninstall:
        uninstall(layout)
        return 0
    if args.verify:
        return 0 if verify(args.domain_id, args.timeout) else 1

    if importlib.util.find_spec("rclpy") is None:
        log("rclpy is not installed (no ROS 2 in this environment); nothing to build")
        return 0
    ok, where = tf2_msgs_status()
    if ok and not args.force:
        log(f"tf2_msgs already available ({where}); nothing to do")
        return 0
    if not ok:
        log(f"tf2_msgs not usable ({where}); building it into {layout.prefix}")
    try:
        build_and_install(layout, args.keep_build)
    except BuildError as exc:
        log(f"ERROR: {exc}")
        return 2
    ok, where = tf2_msgs_status()
    if not ok:
        log(f"ERROR: built, but tf2_msgs still does not import: {where}")
        return 1
    log(f"tf2_msgs imports from {where}")
    if args.no_verify:
        return 0
    return 0 if verify(args.domain_id, args.timeout) else 1


if __name__ == "__main__":
    sys.exit(main())
