"""Initial estimates of the measurement frame and the tool point, before the geometry is calibrated.

The measurement frame (where the robot base is in the tracker's / camera's frame) by a rigid fit
(``Rotation.align_vectors``) of the nominal predictions to the measurements; the measured point on
the flange by linear least squares given that frame; the two alternated. With orientation data the
mean tool orientation error too. :func:`_analysis_model` is the nominal geometry with the estimated
tool point, at which the identifiability analysis is repeated.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_Rt
from plugins.calibration.kinematics.data import KinematicSamples
from plugins.robot.kinematics import RobotModel

F64 = NDArray[np.float64]


def initial_measurement_frame(model: RobotModel, samples: KinematicSamples) -> F64:
    """Rigid transform mapping the model's world to the measurement frame (least squares on positions)."""
    pred = model.fk(samples.q)[:, :3, 3]
    meas = samples.positions
    cp, cm = pred.mean(axis=0), meas.mean(axis=0)
    rot, _ = Rotation.align_vectors(meas - cm, pred - cp)
    R = rot.as_matrix()
    return T_from_Rt(R, cm - R @ cp)


def _fit_tool_point(model: RobotModel, samples: KinematicSamples) -> RobotModel:
    """Tool point (flange frame) that best explains the measurements given the model's base."""
    F = _flange_frames(model, samples.q)
    A = F[:, :3, :3].reshape(-1, 3)
    b = (samples.positions - F[:, :3, 3]).reshape(-1)
    p_flange, *_ = np.linalg.lstsq(A, b, rcond=None)
    return _with_tool_point(model, p_flange)


def _with_tool_point(model: RobotModel, p_flange: F64) -> RobotModel:
    """Set ``tool.tx ty tz`` so that the TCP origin sits at ``p_flange`` in the flange frame."""
    v = model.param_values.copy()
    idx = [model.chain.index(f"tool.{k}") for k in ("tx", "ty", "tz")]
    fixed = model.T_flange_tcp[:3, 3] - v[idx]
    v[idx] = p_flange - fixed
    return model.with_values(v)


def initial_frames(model: RobotModel, samples: KinematicSamples, base: bool, tool: bool, rounds: int = 5) -> RobotModel:
    """Initial measurement frame (rigid fit) and tool point (linear least squares), alternated."""
    for _ in range(rounds if base and tool else 1):
        if base:
            model = model.with_base(initial_measurement_frame(model, samples) @ model.T_world_base)
        if tool:
            model = _fit_tool_point(model, samples)
    if tool and samples.full_pose:  # mean orientation error, applied about the TCP axes
        R_model = model.fk(samples.q)[:, :3, :3]
        R_err = Rotation.from_matrix(np.swapaxes(R_model, 1, 2) @ samples.rotations).mean().as_matrix()
        T_fixed = model._fixed_matrix("tool")
        model = model.with_tool(T_fixed @ T_from_Rt(R_err, np.zeros(3)))
    return model


def _flange_frames(model: RobotModel, q: F64) -> F64:
    g = model.chain.evaluate(q, record_groups=True).group_frames
    return g.get("flange", g[f"joint{model.dof}"])


def _analysis_model(initial: RobotModel, estimate: RobotModel, q: F64) -> RobotModel:
    """Nominal joint geometry with the tool point moved to where the estimate puts it."""
    F = _flange_frames(initial, q)
    p_world = estimate.fk(q)[:, :3, 3]
    R_T = np.swapaxes(F[:, :3, :3], 1, 2)
    p_flange = np.mean((R_T @ (p_world - F[:, :3, 3])[:, :, None])[:, :, 0], axis=0)
    return _with_tool_point(initial, p_flange)
