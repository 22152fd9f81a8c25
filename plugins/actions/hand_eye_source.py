"""Where an action stage takes its hand-eye transform from: a pose in the recipe or a calibration
result file (``vgr calibrate ... --json``, or ``result.json`` in a calibration run's folder), whose
verdict must allow it to drive a robot."""

from __future__ import annotations

import json

import numpy as np

from engine.stage import StageContext
from engine.transforms import as_transform
from plugins.params import PoseSpec


def hand_eye_name(mode: str) -> str:
    """The transform a *mode* needs: ``T_tcp_cam`` (camera on the flange) or ``T_base_cam`` (fixed)."""
    return "T_tcp_cam" if mode == "eye_in_hand" else "T_base_cam"


def load_hand_eye(ctx: StageContext, mode: str, pose: PoseSpec | None, result_file: str | None) -> np.ndarray:
    """The hand-eye transform of *mode* from *result_file* (relative: to the recipe) or *pose*
    (ValueError when neither is given, or the file's verdict is not ``ok``/``warning``)."""
    want = hand_eye_name(mode)
    if result_file:
        path = ctx.input_path(result_file)
        doc = json.loads(path.read_text())
        if doc.get("verdict") not in ("ok", "warning"):
            raise ValueError(f"{path}: calibration verdict {doc.get('verdict')!r} may not drive a robot")
        if want not in doc.get("estimate", {}):
            raise ValueError(f"{path}: no {want} in the calibration estimate (mode {mode})")
        return as_transform(np.array(doc["estimate"][want], dtype=float), name=want)
    if pose is None:
        raise ValueError(f"{ctx.name} needs the hand-eye transform {want}: set hand_eye or hand_eye_file")
    return pose.T()
