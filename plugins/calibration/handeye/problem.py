"""The two hand-eye set-ups written as one equation, ``A_i X B_i = Y`` for every sample i.

Inputs are always the measured robot poses ``M_i = T_base_tcp_i`` and camera observations
``B_i = T_cam_target_i`` (seed 000's T_tcp2base and T_cam2target).

``eye_in_hand`` (camera on the flange, target fixed in the cell)::

    T_base_tcp_i T_tcp_cam T_cam_target_i = T_base_target     A_i = M_i,    X = T_tcp_cam, Y = T_base_target

``eye_to_hand`` (camera fixed, target on the flange)::

    T_tcp_base_i T_base_cam T_cam_target_i = T_tcp_target      A_i = M_i^-1, X = T_base_cam, Y = T_tcp_target

Both are the robot-world problem ``A_i X = Y B_i^-1`` (seed 000's AX = ZB with Z = Y); eliminating Y
between samples i and j gives the hand-eye problem on relative motions
``(A_j^-1 A_i) X = X (B_j B_i^-1)`` (AX = XB).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from engine.transforms import inv

F64 = NDArray[np.float64]

Setup = Literal["eye_in_hand", "eye_to_hand"]
SETUPS: tuple[Setup, ...] = ("eye_in_hand", "eye_to_hand")

__all__ = [
    "SETUPS",
    "RelativeMotions",
    "Setup",
    "SetupFrames",
    "chain_poses",
    "check_setup",
    "frames_of",
    "model_camera_poses",
    "relative_motions",
    "robot_A",
]


@dataclass(frozen=True)
class SetupFrames:
    """Names of the unknowns of one set-up and of the frames they are expressed in."""

    x_name: str  # the hand-eye transform
    y_name: str  # the other unknown (fixed target in base, or target on the flange)
    x_parent: str  # frame in which X's perturbations (and relative-motion axes) are expressed
    y_parent: str


_FRAMES: dict[str, SetupFrames] = {
    "eye_in_hand": SetupFrames("T_tcp_cam", "T_base_target", "tcp", "base"),
    "eye_to_hand": SetupFrames("T_base_cam", "T_tcp_target", "base", "tcp"),
}


def check_setup(setup: str) -> Setup:
    """Return *setup* if it is a known set-up, else raise ValueError listing the known ones."""
    if setup not in _FRAMES:
        raise ValueError(f"unknown hand-eye set-up {setup!r}; use one of {list(_FRAMES)}")
    return setup  # type: ignore[return-value]


def frames_of(setup: Setup) -> SetupFrames:
    return _FRAMES[check_setup(setup)]


def robot_A(setup: Setup, T_base_tcp: F64) -> F64:
    """The left factor ``A_i`` of ``A_i X B_i = Y`` from the robot poses ``(n, 4, 4)``."""
    return T_base_tcp.copy() if check_setup(setup) == "eye_in_hand" else inv(T_base_tcp)


def chain_poses(setup: Setup, T_base_tcp: F64, X: F64, T_cam_target: F64) -> F64:
    """``Y_i = A_i X B_i`` for every sample: what each sample alone says Y is (the pose chain)."""
    A = robot_A(setup, T_base_tcp)
    return A @ X @ T_cam_target


def model_camera_poses(setup: Setup, T_base_tcp: F64, X: F64, Y: F64) -> F64:
    """Camera observations predicted by the model: ``B_i = X^-1 A_i^-1 Y``."""
    A_inv = inv(robot_A(setup, T_base_tcp))
    return inv(X) @ A_inv @ Y


@dataclass(frozen=True)
class RelativeMotions:
    """Relative motions ``A_ij X = X B_ij`` for sample pairs ``pairs[k] = (i, j)``, i < j."""

    A: F64  # (k, 4, 4) robot motion, in X's parent frame
    B: F64  # (k, 4, 4) camera motion, in X's child frame
    pairs: NDArray[np.int64]  # (k, 2)


def relative_motions(setup: Setup, T_base_tcp: F64, T_cam_target: F64, pairs: str = "all") -> RelativeMotions:
    """Relative motions of every pair (``pairs="all"``) or of consecutive samples (``"consecutive"``).

    ``A_ij = A_j^-1 A_i`` and ``B_ij = B_j B_i^-1`` so that ``A_ij X = X B_ij`` for every pair.
    """
    A = robot_A(setup, T_base_tcp)
    n = A.shape[0]
    if pairs == "all":
        ii, jj = np.triu_indices(n, k=1)
    elif pairs == "consecutive":
        ii, jj = np.arange(n - 1), np.arange(1, n)
    else:
        raise ValueError(f"pairs must be 'all' or 'consecutive', got {pairs!r}")
    A_inv = inv(A)
    B_inv = inv(T_cam_target)
    return RelativeMotions(
        A=A_inv[jj] @ A[ii],
        B=T_cam_target[jj] @ B_inv[ii],
        pairs=np.stack([ii, jj], axis=1).astype(np.int64),
    )
