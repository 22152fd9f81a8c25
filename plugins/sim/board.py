"""A calibration board fixed in the simulated cell: its plate for the depth camera, its printed face
for the camera's intensity image.

The board (any :class:`plugins.camera.board_spec.BoardSpec`: chessboard, ChArUco, circle grid) is
a :class:`Workpiece` like the cell's other parts, so the depth camera sees it and its frame goes in
the frame tree like theirs: a plate ``thickness_m`` thick under the printed face, which is the plane
z = 0 of the board frame ``target`` (:mod:`plugins.camera.board_spec`: origin at the first feature,
+z out of the printed face), as wide as the printed sheet with its white margin.

The intensity image is rendered by the board library's renderer
(:func:`plugins.camera.board_render.render_board`: each pixel the average of supersampled rays
through the lens model, Gaussian defocus blur, Gaussian grey-level noise from the caller's seeded
generator) seen through :attr:`BoardImager.camera`, a pinhole with lens distortion: the depth
camera's intrinsics with the distortion ``D`` of OpenCV's standard model. A real depth camera
delivers its depth rectified and its raw intensity (IR or colour) image distorted, with the
distortion in its CameraInfo: the simulated one does the same. Only the board is drawn in the
intensity image (other parts are not); rays that miss it see a uniform grey.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
import open3d as o3d
from numpy.typing import ArrayLike, NDArray

from plugins.camera.board_render import board_texture, render_board
from plugins.camera.board_spec import BoardSpec
from plugins.camera.pinhole import CameraModel
from plugins.util.workpieces import Workpiece

__all__ = ["BoardImager", "board_workpiece"]

BOARD_THICKNESS_M = 0.004


@cache
def _extent(board: BoardSpec) -> tuple[float, float, float, float]:
    """``(x0, x1, y0, y1)`` of the printed sheet (the board's texture with its margin), board frame."""
    tex = board_texture(board, texels_per_square=8)
    h, w = tex.image.shape
    return tex.x0, tex.x0 + w * tex.texel_m, tex.y1 - h * tex.texel_m, tex.y1


def board_workpiece(board: BoardSpec, name: str = "board", thickness_m: float = BOARD_THICKNESS_M) -> Workpiece:
    """The board's plate as a workpiece: a box under the printed sheet, its top face at z = 0."""
    if not (np.isfinite(thickness_m) and thickness_m > 0):
        raise ValueError(f"board thickness must be positive, got {thickness_m}")
    x0, x1, y0, y1 = _extent(board)
    mesh = o3d.geometry.TriangleMesh.create_box(x1 - x0, y1 - y0, thickness_m)
    mesh.translate((x0, y0, -thickness_m))
    return Workpiece(
        name=name,
        mesh=mesh,
        features={},
        feature_radii={},
        feature_axes={},
        symmetric=board.ambiguous,
        description=f"calibration board {board.describe()} on a {thickness_m * 1e3:g} mm plate",
        size_m=np.array([x1 - x0, y1 - y0, thickness_m]),
    )


@dataclass(frozen=True, eq=False)
class BoardImager:
    """The intensity image of a board: the lens model, blur, noise and the renderer's supersampling."""

    board: BoardSpec
    camera: CameraModel
    noise_sigma: float = 2.0  # grey levels
    blur_sigma_px: float = 0.5
    supersample: int = 3

    def __post_init__(self) -> None:
        if not (np.isfinite(self.noise_sigma) and self.noise_sigma >= 0):
            raise ValueError(f"image noise must be >= 0 grey levels, got {self.noise_sigma}")
        if not (np.isfinite(self.blur_sigma_px) and self.blur_sigma_px >= 0):
            raise ValueError(f"image blur must be >= 0 px, got {self.blur_sigma_px}")
        if not 1 <= int(self.supersample) <= 8:
            raise ValueError(f"supersample must be 1-8, got {self.supersample}")

    @classmethod
    def for_depth_camera(
        cls, board: BoardSpec, depth_camera: CameraModel, distortion: ArrayLike, **options: float
    ) -> BoardImager:
        """The imager of a depth camera's intensity image: the depth camera's intrinsics, the given
        distortion ``(k1, k2, p1, p2, k3)``."""
        camera = CameraModel(depth_camera.width, depth_camera.height, depth_camera.K, np.asarray(distortion, float))
        return cls(board, camera, **options)  # type: ignore[arg-type]

    def render(self, T_cam_board: ArrayLike, rng: np.random.Generator) -> NDArray[np.uint8]:
        """The 8-bit grey image ``(height, width)`` of the board seen from ``T_cam_board``."""
        return render_board(
            self.board,
            self.camera,
            T_cam_board,
            supersample=int(self.supersample),
            blur_sigma_px=self.blur_sigma_px,
            noise_sigma=self.noise_sigma,
            rng=rng,
        )
