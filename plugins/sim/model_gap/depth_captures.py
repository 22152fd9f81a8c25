"""Simulated depth captures of a flat target with a hidden depth effect: the ground truth of the depth
model-gap tests and of benchmarks/depth_gap.py.

The simulated depth camera (:class:`plugins.sim.camera.DepthCameraModel`, 80 x 60 px by default, 60
degrees horizontal field of view, noise ``sigma(z) = 0.2 mm + 1e-3 / m * z^2``: a small
structured-light camera) sees a flat plate (3 m x 3 m, its top face the ``z = 0`` plane of its
frame, so it fills the image) from random poses: distance to the plate's centre 0.4-1.2 m, the view
tilted up to 35 degrees from the plate's normal, rolled at random. Each capture is rendered by ray
casting with the hidden effect injected by the sensor model itself (:class:`DepthNoiseModel`'s
``depth_scale``, ``depth_bias_m``, ``depth_quad_per_m``, ``bias_pattern``, ``wiggle_*``);
``T_cam_target`` is the truth. Gross errors (``outlier_fraction``): that share of pixels moved along
their ray by 2-20 cm, either sign (flying pixels). :data:`EFFECT_NOISE` holds each effect's hidden
magnitude at scale 1: about 1-2 mm where it acts, a few times the noise at 0.5 m.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from engine.transforms import inv
from plugins.camera.pinhole import CameraModel
from plugins.model_gap.depth.data import DepthCaptures, DepthFrame, SigmaLaw
from plugins.sim.camera import DepthCameraModel, DepthNoiseModel, look_at

F64 = NDArray[np.float64]

__all__ = ["EFFECT_NOISE", "SIM_NOISE", "SIM_SIZE", "effect_noise", "simulate_captures"]

SIM_SIZE = (80, 60)
SIM_NOISE = DepthNoiseModel(sigma_const_m=2e-4, sigma_quad_per_m=1e-3, grazing_dropout_deg=85.0)
PLATE_M = 3.0

#: each depth effect's hidden DepthNoiseModel fields at scale 1
EFFECT_NOISE: dict[str, dict[str, Any]] = {
    "range_scale": {"depth_scale": 1.0 + 2e-3},
    "range_bias": {"depth_bias_m": 1.5e-3},
    "range_quadratic": {"depth_quad_per_m": 2.5e-3},
    "radial_pattern": {"bias_pattern": ((2, 0, 3e-3), (0, 2, 3e-3), (4, 0, 4e-3), (2, 2, 8e-3), (0, 4, 4e-3))},
    "polynomial_pattern": {"bias_pattern": ((1, 0, 1.5e-3), (1, 1, 5e-3), (0, 2, -4e-3))},
    "wiggling": {"wiggle_amplitude_m": 1.2e-3, "wiggle_period_m": 0.1874, "wiggle_phase_rad": 0.7},
}


def effect_noise(effect: str | None, scale: float = 1.0, base: DepthNoiseModel = SIM_NOISE) -> DepthNoiseModel:
    """*base* with *effect* hidden at *scale* times its :data:`EFFECT_NOISE` magnitude."""
    if effect is None:
        return base
    if effect not in EFFECT_NOISE:
        raise ValueError(f"no simulated depth effect {effect!r}: {', '.join(EFFECT_NOISE)}")
    fields = dict(EFFECT_NOISE[effect])
    if "depth_scale" in fields:
        fields["depth_scale"] = 1.0 + scale * (float(fields["depth_scale"]) - 1.0)
    for key in ("depth_bias_m", "depth_quad_per_m", "wiggle_amplitude_m"):
        if key in fields:
            fields[key] = scale * float(fields[key])
    if "bias_pattern" in fields:
        fields["bias_pattern"] = tuple((i, j, scale * c) for i, j, c in fields["bias_pattern"])
    return replace(base, **fields)


def _plate() -> o3d.geometry.TriangleMesh:
    mesh = o3d.geometry.TriangleMesh.create_box(PLATE_M, PLATE_M, 0.02)
    mesh.translate((-PLATE_M / 2, -PLATE_M / 2, -0.02))
    return mesh


def _camera_pose(rng: np.random.Generator, near: float, far: float, max_tilt_deg: float) -> F64:
    """T_target_cam: the camera at *near*-*far* m from a point near the plate's centre, tilted."""
    dist = rng.uniform(near, far)
    tilt = math.radians(max_tilt_deg) * math.sqrt(rng.uniform())
    azim = rng.uniform(0.0, 2.0 * math.pi)
    view = np.array([math.sin(tilt) * math.cos(azim), math.sin(tilt) * math.sin(azim), math.cos(tilt)])
    target = np.array([*rng.uniform(-0.05, 0.05, 2), 0.0])
    roll = rng.uniform(0.0, 2.0 * math.pi)
    up = np.array([math.cos(roll), math.sin(roll), 0.0])
    if abs(up @ view) > 0.95:
        up = np.array([-math.sin(roll), math.cos(roll), 0.0])
    return look_at(target + dist * view, target, up)


def simulate_captures(
    effect: str | None = None,
    *,
    scale: float = 1.0,
    n: int = 16,
    seed: int = 0,
    size: tuple[int, int] = SIM_SIZE,
    noise: DepthNoiseModel | None = None,
    outlier_fraction: float = 0.0,
    near_m: float = 0.4,
    far_m: float = 1.2,
    max_tilt_deg: float = 35.0,
    stated_noise: bool = False,
) -> DepthCaptures:
    """*n* captures of the plate with *effect* hidden (module docstring); ``stated_noise``: the
    captures carry the simulator's true noise law as the sensor's stated one."""
    rng = np.random.default_rng(seed)
    w, h = size
    f = (w / 2.0) / math.tan(math.radians(30.0))
    intr = CameraModel.pinhole(w, h, f, f, (w - 1) / 2.0, (h - 1) / 2.0)
    model = noise if noise is not None else effect_noise(effect, scale)
    cam = DepthCameraModel(intr, model, min_range_m=0.1, max_range_m=5.0)
    plate = _plate()
    frames = []
    for k in range(n):
        T_target_cam = _camera_pose(rng, near_m, far_m, max_tilt_deg)
        cap = cam.render([(plate, np.eye(4))], T_target_cam, rng)
        depth = cap.depth.astype(float)
        if outlier_fraction > 0:
            _flying(depth, intr, outlier_fraction, rng)
        frames.append(DepthFrame(f"capture_{k:02d}", depth, inv(T_target_cam)))
    sigma = SigmaLaw(model.sigma_const_m, model.sigma_quad_per_m) if stated_noise else None
    return DepthCaptures(frames, np.asarray(intr.K, float), size, None, sigma, f"simulated ({effect or 'no effect'})")


def _flying(depth: F64, intr: CameraModel, fraction: float, rng: np.random.Generator) -> None:
    """Move *fraction* of the valid pixels along their ray by 2-20 cm, either sign (in place)."""
    valid = np.flatnonzero(np.isfinite(depth.ravel()))
    pick = rng.choice(valid, size=max(1, round(fraction * len(valid))), replace=False)
    v, u = np.divmod(pick, intr.width)
    norm = np.sqrt(1.0 + ((u - intr.cx) / intr.fx) ** 2 + ((v - intr.cy) / intr.fy) ** 2)
    shift = rng.uniform(0.02, 0.2, len(pick)) * rng.choice((-1.0, 1.0), len(pick))
    flat = depth.reshape(-1)
    flat[pick] = np.maximum(flat[pick] + shift / norm, 0.05)
