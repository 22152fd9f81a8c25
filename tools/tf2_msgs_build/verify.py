"""Checking an installed tf2_msgs: does it import with type support, and does a round trip work."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from .cdr import EXPECTED_DDS_TYPE
from .common import ENTRY_POINT, log

DEFAULT_DOMAIN_ID = 91
ROUND_TRIP_TIMEOUT_S = 10.0
SELFTEST_TOPIC = "/vgr_tf2_msgs_selftest"

IMPORT_CHECK = """
import sys
from tf2_msgs.msg import TFMessage
TFMessage.__class__.__import_type_support__()
if TFMessage.__class__._TYPE_SUPPORT is None:
    sys.exit("tf2_msgs imports but its type support does not load")
import tf2_msgs
print(tf2_msgs.__path__[0])
"""


def tf2_msgs_status() -> tuple[bool, str]:
    """Whether ``tf2_msgs`` imports with working type support, in a fresh interpreter.

    Returns (ok, location-or-error).  A fresh process is used so that libraries
    installed by this run are picked up and this process's imports are untouched.
    """
    proc = subprocess.run([sys.executable, "-c", IMPORT_CHECK], capture_output=True, text=True, timeout=60, check=False)
    if proc.returncode == 0:
        return True, proc.stdout.strip()
    tail = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
    return False, tail


def verify(domain_id: int, timeout_s: float) -> bool:
    """Publish/subscribe round trip between two fresh processes on loopback (selftest's children)."""
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    cmd = [sys.executable, str(ENTRY_POINT), "--_subscriber", "--topic", SELFTEST_TOPIC, "--timeout", str(timeout_s)]
    try:
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout_s + 30, check=False)
    except subprocess.TimeoutExpired:
        log("verification timed out")
        return False
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    if not lines:
        log(f"verification failed (exit {proc.returncode}):\n{proc.stdout}{proc.stderr}")
        return False
    report = json.loads(lines[-1])
    log("round trip: " + json.dumps(report, sort_keys=True))
    if proc.returncode != 0:
        log(f"verification FAILED (exit {proc.returncode}){chr(10) + proc.stderr if proc.stderr else ''}")
        return False
    log(f"verification OK: {EXPECTED_DDS_TYPE} round trip over Fast DDS (domain {domain_id}, localhost)")
    return True
