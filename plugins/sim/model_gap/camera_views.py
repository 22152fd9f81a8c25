"""Simulated board detections with a hidden camera effect: the ground truth of the camera model-gap
tests and of benchmarks/camera_gap.py.

A camera (1280 x 960 px, f = 1000 px, Brown radial k1 = -0.25, k2 = 0.08: an ordinary lens) sees a
chessboard (``chessboard:12x9:25mm``, 88 inner corners) from random poses
(:func:`plugins.camera.board_render.sample_views`: the whole board in the image, tilted up to 45
degrees); each corner is projected by ``cv2.projectPoints`` with the true 14-coefficient distortion
vector (the baseline's k1, k2 plus the hidden effect's coefficients) and Gaussian noise of
``noise_px`` per coordinate is added: what a detector gives (detected-corner level, no image). A
board that is not flat (``board_bow_m``) is the off-catalog control. The
hidden effects' default coefficients (:data:`EFFECT_COEFFICIENTS`) move the corners by a few tenths
of a pixel beyond what the baseline can absorb; ``scale`` multiplies them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from plugins.calibration.boards.detect import Detection
from plugins.camera.board_render import sample_views
from plugins.camera.board_spec import BoardSpec, parse_board
from plugins.camera.pinhole import CameraModel
from plugins.model_gap.camera.catalog import COEFFICIENTS
from plugins.model_gap.camera.fitting import project_view

F64 = NDArray[np.float64]

__all__ = ["EFFECT_COEFFICIENTS", "SIM_BOARD", "SIM_SIZE", "simulate_detections", "true_distortion"]

SIM_BOARD = "chessboard:12x9:25mm"
SIM_SIZE = (1280, 960)
SIM_K = np.array([[700.0, 0.0, 652.0], [0.0, 700.0, 471.0], [0.0, 0.0, 1.0]])
SIM_BASE = {"k1": -0.3, "k2": 0.1}

#: each catalog effect's hidden coefficients at scale 1
EFFECT_COEFFICIENTS: dict[str, dict[str, float]] = {
    "radial_k3": {"k3": -0.12},
    "tangential": {"p1": 8e-4, "p2": -6e-4},
    "thin_prism": {"s1": 1.5e-3, "s2": 0.0, "s3": -1.5e-3, "s4": 0.0},
    "rational": {"k4": 0.6, "k5": -0.3, "k6": 0.2},
    "tilted": {"tauX": 4e-3, "tauY": -3e-3},
}


def true_distortion(effect: str | None, scale: float = 1.0) -> F64:
    """The true 14-coefficient distortion vector: the baseline lens plus *effect* times *scale*."""
    coeffs = dict(SIM_BASE)
    if effect is not None:
        if effect not in EFFECT_COEFFICIENTS:
            raise ValueError(f"no simulated effect {effect!r}: {', '.join(EFFECT_COEFFICIENTS)}")
        coeffs.update({k: scale * v for k, v in EFFECT_COEFFICIENTS[effect].items()})
    if effect == "rational":  # the numerator keeps the lens: (1 + k1 r2 ..) / (1 + k4 r2 ..) needs k1 - k4 more
        coeffs["k1"] = SIM_BASE["k1"] + coeffs["k4"]
    return np.array([coeffs.get(c, 0.0) for c in COEFFICIENTS])


def _bowed(points: F64, bow_m: float) -> F64:
    """The board points on a paraboloid whose centre lies *bow_m* above (+z) the board's corners."""
    xy = points[:, :2] - points[:, :2].mean(axis=0)
    r2 = np.sum(xy**2, axis=1)
    out = points.copy()
    out[:, 2] += bow_m * (1.0 - r2 / r2.max())
    return out


def simulate_detections(
    effect: str | None,
    *,
    n_views: int = 20,
    noise_px: float = 0.1,
    scale: float = 1.0,
    seed: int = 0,
    board: BoardSpec | None = None,
    board_bow_m: float = 0.0,
) -> tuple[list[Detection], tuple[int, int]]:
    """*n_views* simulated detections of the board with *effect* hidden (None: the baseline lens
    alone) and the image size; views whose corners would leave the image are drawn again.
    ``board_bow_m``: the printed board is not flat but bowed, its centre *board_bow_m* above its
    corners (a paraboloid; outside the catalog), while the detections keep the flat board's points."""
    board = board or parse_board(SIM_BOARD)
    true_points = _bowed(board.object_points, board_bow_m)
    rng = np.random.default_rng(seed)
    D = true_distortion(effect, scale)
    w, h = SIM_SIZE
    plain = CameraModel(w, h, SIM_K, np.array([SIM_BASE["k1"], SIM_BASE["k2"], 0.0, 0.0, 0.0]))
    views: list[Detection] = []
    while len(views) < n_views:
        for T in sample_views(board, plain, n_views - len(views), rng, max_tilt_deg=45.0, margin_px=20.0):
            import cv2

            rvec = np.asarray(cv2.Rodrigues(T[:3, :3])[0], float)
            uv = project_view(SIM_K, D, rvec, T[:3, 3].reshape(3, 1), true_points)
            if not (np.all(uv > 2.0) and np.all(uv < np.array([w - 3.0, h - 3.0]))):
                continue
            uv = uv + rng.normal(0.0, noise_px, uv.shape)
            ids = np.arange(board.n_features, dtype=np.int64)
            name = f"sim_{len(views):03d}.png"
            views.append(Detection(name, (w, h), ids, uv, board.object_points.copy(), "simulated"))
    return views, (w, h)
