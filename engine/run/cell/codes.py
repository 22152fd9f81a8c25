"""The one status-code table of every cell-service reply (zenoh API and TCP gateway alike).

A controller acts on the number; the name is what the JSON replies carry as ``status``. Motion is
allowed on ``ok`` alone: every other code means "do not apply a correction from this reply".

====  ======================  ==============================================================================
code  status                  meaning, and what a controller does
====  ======================  ==============================================================================
0     ``ok``                  done: apply the result (correction, next move) as it is
1     ``no_part``             nothing matched the template in the capture (no part, wrong part, empty tray)
2     ``ambiguous``           several poses fit about equally well: nothing can be chosen safely
3     ``out_of_limits``       a correction or step beyond the recipe's limits (or not finite): refused
4     ``not_converged``       iterative guidance used its step budget without reaching the tolerance
5     ``camera_fault``        the camera did not deliver (timeout, disconnect, no data); the service retries
6     ``robot_pose_invalid``  the pose sent is missing, not finite, or not a rigid transform
7     ``busy``                another cycle is running: ask again after it (requests are not queued)
8     ``invalid_request``     the request is malformed: unknown command, bad JSON, a field of the wrong type
9     ``fault``               vgr itself failed on this request (a stage raised): see the service's log
10    ``stopping``            the service is stopping (Ctrl-C, SIGTERM, ``stop``): no new cycle starts
====  ======================  ==============================================================================

A leaf module: it imports nothing of vgr.
"""

from __future__ import annotations

from enum import IntEnum


class Status(IntEnum):
    ok = 0
    no_part = 1
    ambiguous = 2
    out_of_limits = 3
    not_converged = 4
    camera_fault = 5
    robot_pose_invalid = 6
    busy = 7
    invalid_request = 8
    fault = 9
    stopping = 10


STATUS_NAMES: tuple[str, ...] = tuple(s.name for s in Status)


def code_of(status: str) -> int:
    """The number of status *status* (``fault``'s for a name the table does not have)."""
    member = Status.__members__.get(status)
    return int(member if member is not None else Status.fault)
