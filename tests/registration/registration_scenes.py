"""Simulated captures with ground truth for the registration tests and benchmark (plugins.sim).

A part is placed in front of a fixed camera (OpenCV frame, z forward) with its top face towards the
camera; the template capture sees it at a nominal pose, the current capture at a perturbed pose. The
true ``T_match = T_camT_part @ inv(T_camC_part)`` maps current points onto the template points.
Only the part is rendered (no table): the part is held by the robot in front of a fixed sensor, as
in seed 004's eye-to-hand set-up.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from engine import transforms as tf
from plugins.camera.pinhole import CameraModel
from plugins.sim.camera import DepthCameraModel, DepthNoiseModel
from plugins.util.workpieces import Workpiece, make_workpiece

#: Working distance (m) of the camera to the part's top face.
DISTANCE_M = 0.5


@cache
def workpiece(name: str) -> Workpiece:
    return make_workpiece(name)


def camera(width: int = 640, height: int = 480, sigma_m: float = 1e-4, hfov_deg: float = 60.0) -> DepthCameraModel:
    """Pinhole depth camera with ``sigma_m`` depth noise (0.1 mm default) and 80 deg grazing dropout."""
    f = (width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
    k = CameraModel.pinhole(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)
    return DepthCameraModel(k, DepthNoiseModel(sigma_const_m=sigma_m), min_range_m=0.1, max_range_m=2.0)


def part_center(name: str) -> np.ndarray:
    """Centre of the part's bounding box in the part frame (m): where errors are measured."""
    V = workpiece(name).vertices()
    return 0.5 * (V.min(axis=0) + V.max(axis=0))


def nominal_pose(name: str, view_tilt_deg: float = 0.0) -> np.ndarray:
    """T_cam_part of the template: part centre on the optical axis, top face towards the camera,
    turned by ``view_tilt_deg`` about the part's X axis (an oblique view shows side walls)."""
    wp = workpiece(name)
    top = float(wp.vertices()[:, 2].max())
    R = np.diag([1.0, -1.0, -1.0])  # part Z towards the camera (-z_cam)
    R = R @ Rotation.from_euler("x", view_tilt_deg, degrees=True).as_matrix()
    c = part_center(name)
    c_top = np.array([c[0], c[1], top])
    return tf.T_from_Rt(R, np.array([0.0, 0.0, DISTANCE_M]) - R @ c_top)


def perturbed_pose(
    name: str,
    rng: np.random.Generator,
    *,
    max_shift_m: float,
    max_tilt_deg: float,
    spin_deg: float | None,
    view_tilt_deg: float = 0.0,
) -> np.ndarray:
    """A current T_cam_part: the nominal pose moved in the part frame by a random shift (|x|,|y| <=
    max_shift_m, |z| <= max_shift_m / 2), a tilt <= max_tilt_deg and a spin about the part Z (uniform
    in [-180, 180) when ``spin_deg`` is None, else uniform in [-spin_deg, spin_deg])."""
    c = part_center(name)
    spin = rng.uniform(-180.0, 180.0) if spin_deg is None else rng.uniform(-spin_deg, spin_deg)
    tilt_axis = rng.normal(size=2)
    tilt_axis = np.array([*tilt_axis / np.linalg.norm(tilt_axis), 0.0])
    R = Rotation.from_rotvec(np.radians(rng.uniform(0.0, max_tilt_deg)) * tilt_axis).as_matrix()
    R = R @ Rotation.from_euler("z", spin, degrees=True).as_matrix()
    shift = rng.uniform(-max_shift_m, max_shift_m, 3) * np.array([1.0, 1.0, 0.5])
    # rotate about the part centre, then shift
    T_move = tf.T_from_Rt(R, c - R @ c + shift)
    return nominal_pose(name, view_tilt_deg) @ T_move


@dataclass
class Capture:
    points: np.ndarray
    T_cam_part: np.ndarray


def capture(name: str, T_cam_part: np.ndarray, cam: DepthCameraModel, rng: np.random.Generator) -> Capture:
    """Render the part at ``T_cam_part`` (camera at the world origin)."""
    cap = cam.render([(workpiece(name), T_cam_part)], np.eye(4), rng)
    return Capture(cap.points, T_cam_part)


def capture_pair(
    name: str, cam: DepthCameraModel, rng: np.random.Generator, **perturbation: Any
) -> tuple[Capture, Capture]:
    """(template, current): captures at the nominal pose and at a pose perturbed from it by
    :func:`perturbed_pose` with *perturbation* (``max_shift_m``, ``max_tilt_deg``, ``spin_deg``)."""
    template = capture(name, nominal_pose(name), cam, rng)
    return template, capture(name, perturbed_pose(name, rng, **perturbation), cam, rng)


def model_template(name: str, T_cam_part: np.ndarray, spacing_m: float, rng: np.random.Generator) -> Capture:
    """A template made from the CAD model (seed 004): the part's surface sampled at about
    ``spacing_m`` (area-weighted), keeping the side a sensor above the part can see (surface normal
    with a part-Z component > -0.5, so the bottom face is left out), placed at ``T_cam_part``."""
    wp = workpiece(name)
    area = wp.mesh.get_surface_area()
    pts, nrm = wp.sample_points(int(area / spacing_m**2), rng)
    keep = nrm[:, 2] > -0.5
    return Capture(tf.transform_points(T_cam_part, pts[keep]), T_cam_part)


def at_distance(T_cam_part: np.ndarray, distance_m: float) -> np.ndarray:
    """The pose moved along the optical axis by ``distance_m - DISTANCE_M`` (the part's face at
    ``distance_m`` for a nominal pose)."""
    return tf.T_from_Rt(np.eye(3), [0.0, 0.0, distance_m - DISTANCE_M]) @ T_cam_part


def true_match(template: Capture, current: Capture) -> np.ndarray:
    return template.T_cam_part @ tf.inv(current.T_cam_part)


def match_error(T_est: np.ndarray, template: Capture, current: Capture, name: str) -> tuple[float, float]:
    """(mm, deg): displacement of the part centre (current frame) and rotation angle, estimate vs truth."""
    T_true = true_match(template, current)
    c = tf.transform_points(current.T_cam_part, part_center(name)[None, :])
    dt = np.linalg.norm(tf.transform_points(T_est, c) - tf.transform_points(T_true, c))
    return float(dt * 1e3), float(np.degrees(tf.angle_between(T_est[:3, :3], T_true[:3, :3])))


def flat_table(cam: DepthCameraModel, rng: np.random.Generator, depth_m: float = DISTANCE_M + 0.008) -> np.ndarray:
    """Capture of an empty fixture: a 0.3 x 0.25 m flat table top at ``depth_m`` around the optical
    axis (the part that should lie on it is missing)."""
    import open3d as o3d

    box = o3d.geometry.TriangleMesh.create_box(0.3, 0.25, 0.02)
    box.translate((-0.15, -0.125, depth_m))
    return cam.render([(box, np.eye(4))], np.eye(4), rng).points
