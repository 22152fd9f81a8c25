"""Synthetic images of a calibration board with known truth: camera, distortion, pose, blur, noise.

For tests, benchmarks and the simulated camera. The board is a texture (a chessboard drawn here, a
ChArUco board from OpenCV's ``generateImage``, circles drawn with OpenCV) on the plane z = 0 of the
board frame; every output pixel is ``supersample`` x ``supersample`` rays, each undistorted through
the camera model (:meth:`CameraModel.normalised`, iterated to ~1e-9 px), intersected with the
board plane and looked up in the texture (bilinear), then averaged (the pixel's area). Optional
Gaussian blur (defocus) and Gaussian grey-level noise follow. The true pixel position of every
feature is ``camera.project(T_cam_target, board.object_points)``, which the tests compare with the
detections. Rays that miss the board, or meet its back face, see a uniform background.

Rendering many views with one camera reuses the undistorted ray grid (cached per camera).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from plugins.camera.board_spec import BoardSpec
from plugins.camera.pinhole import CameraModel

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

__all__ = ["BoardTexture", "board_texture", "look_at", "render_board", "sample_views"]

WHITE, BLACK, BACKGROUND = 235, 25, 110


@dataclass(frozen=True, eq=False)
class BoardTexture:
    """A grey image of the board: texel ``(col, row)`` has its centre at board point
    ``(x0 + (col + 0.5) * texel_m, y1 - (row + 0.5) * texel_m)`` (rows run down, y runs up)."""

    image: U8
    texel_m: float
    x0: float
    y1: float


def board_texture(board: BoardSpec, texels_per_square: int = 48, margin_squares: float = 1.0) -> BoardTexture:
    """The board's printed face, with a white margin (detectors need a quiet zone around it)."""
    import cv2

    n = int(texels_per_square)
    s = board.square_m
    res = s / n
    m = round(margin_squares * n)
    if board.kind == "chessboard":
        cols, rows = board.cols, board.rows
        b = np.arange(rows)[::-1, None]  # square row counted from the bottom (the origin's row)
        a = np.arange(cols)[None, :]
        squares = np.where((a + b) % 2 == 0, BLACK, WHITE).astype(np.uint8)
        img = np.kron(squares, np.ones((n, n), np.uint8))
        img = cv2.copyMakeBorder(img, m, m, m, m, cv2.BORDER_CONSTANT, value=WHITE)
        return BoardTexture(img, res, -m * res, rows * s + m * res)
    if board.kind == "charuco":
        w, h = board.cols * n + 2 * m, board.rows * n + 2 * m
        img = board.cv_board().generateImage((w, h), marginSize=m, borderBits=1)
        img = np.where(img > 127, WHITE, BLACK).astype(np.uint8)
        return BoardTexture(img, res, -m * res, board.rows * s + m * res)
    # circles: centres in the board frame, dark discs on white
    pts = board.object_points[:, :2]
    r = 0.5 * board.diameter_m
    pad = r + margin_squares * s
    x0, x1 = pts[:, 0].min() - pad, pts[:, 0].max() + pad
    y0, y1 = pts[:, 1].min() - pad, pts[:, 1].max() + pad
    w, h = int(np.ceil((x1 - x0) / res)), int(np.ceil((y1 - y0) / res))
    img = np.full((h, w), WHITE, np.uint8)
    shift = 4
    for x, y in pts:
        col, row = (x - x0) / res - 0.5, (y1 - y) / res - 0.5
        centre = (round(col * 2**shift), round(row * 2**shift))
        cv2.circle(img, centre, round(r / res * 2**shift), BLACK, -1, cv2.LINE_AA, shift)
    return BoardTexture(img, res, x0, y1)


_RAY_CACHE: dict[tuple[object, ...], F64] = {}


def _rays(camera: CameraModel, supersample: int) -> F64:
    """Normalised undistorted coordinates of every sub-pixel sample, ``(H*ss, W*ss, 2)`` (cached
    for the last few cameras, by their numbers)."""
    key = (camera.width, camera.height, camera.model, camera.K.tobytes(), camera.D.tobytes(), supersample)
    if key in _RAY_CACHE:
        return _RAY_CACHE[key]
    ss = supersample
    off = (np.arange(ss) + 0.5) / ss - 0.5
    u = (np.arange(camera.width)[:, None] + off[None, :]).ravel()
    v = (np.arange(camera.height)[:, None] + off[None, :]).ravel()
    uu, vv = np.meshgrid(u, v)
    xy = camera.normalised(np.column_stack([uu.ravel(), vv.ravel()])).reshape(len(v), len(u), 2)
    if len(_RAY_CACHE) >= 4:
        _RAY_CACHE.pop(next(iter(_RAY_CACHE)))
    _RAY_CACHE[key] = xy
    return xy


def look_at(eye: ArrayLike, target: ArrayLike = (0.0, 0.0, 0.0), up: ArrayLike = (0.0, 1.0, 0.0)) -> F64:
    """``T_cam_target`` of a camera at ``eye`` (board frame, m) looking at ``target`` with the image's
    up direction (-y of the camera) as close to ``up`` as possible."""
    eye, tgt, up_v = (np.asarray(a, dtype=float) for a in (eye, target, up))
    z = tgt - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up_v)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R_target_cam = np.column_stack([x, y, z])
    T = np.eye(4)
    T[:3, :3] = R_target_cam.T
    T[:3, 3] = -R_target_cam.T @ eye
    return T


def render_board(
    board: BoardSpec,
    camera: CameraModel,
    T_cam_target: ArrayLike,
    *,
    supersample: int = 3,
    texels_per_square: int = 48,
    blur_sigma_px: float = 0.0,
    noise_sigma: float = 0.0,
    rng: np.random.Generator | None = None,
    background: int = BACKGROUND,
) -> U8:
    """An 8-bit grey image ``(height, width)`` of the board seen by ``camera`` from ``T_cam_target``.

    ``noise_sigma`` is in grey levels (needs ``rng``); ``blur_sigma_px`` in output pixels."""
    import cv2

    if noise_sigma > 0 and rng is None:
        raise ValueError("noise needs an rng (determinism: every random choice takes a seed)")
    T = np.asarray(T_cam_target, dtype=float)
    tex = board_texture(board, texels_per_square)
    xy = _rays(camera, supersample)
    # ray (x, y, 1) meets the plane z_target = 0: [r1 r2 t] (X, Y, 1) = lambda (x, y, 1)
    Hn = np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]])
    Hinv = np.linalg.inv(Hn)
    h, w = xy.shape[:2]
    rays = np.concatenate([xy, np.ones((h, w, 1))], axis=2)
    q = rays @ Hinv.T
    lam = 1.0 / np.where(q[..., 2] == 0, np.nan, q[..., 2])  # depth along the ray, must be > 0
    X, Y = q[..., 0] * lam, q[..., 1] * lam
    front = T[:3, 2] @ -T[:3, 3] > 0  # the camera lies on the +z side: it sees the printed face
    visible = np.isfinite(lam) & (lam > 0) & front
    col = np.where(visible, (X - tex.x0) / tex.texel_m - 0.5, -1e6).astype(np.float32)
    row = np.where(visible, (tex.y1 - Y) / tex.texel_m - 0.5, -1e6).astype(np.float32)
    fine = cv2.remap(tex.image, col, row, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=background)
    ss = supersample
    img = fine.reshape(camera.height, ss, camera.width, ss).astype(np.float64).mean(axis=(1, 3))
    if blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma_px)
    if noise_sigma > 0:
        assert rng is not None
        img = img + rng.normal(0.0, noise_sigma, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def sample_views(
    board: BoardSpec,
    camera: CameraModel,
    n: int,
    rng: np.random.Generator,
    *,
    distance_m: tuple[float, float] | None = None,
    max_tilt_deg: float = 45.0,
    margin_px: float = 10.0,
    max_tries: int = 10000,
) -> list[F64]:
    """``n`` random poses ``T_cam_target`` from which the whole board (with a margin) is in the image:
    the camera looks at a random point of the board from a random direction tilted up to
    ``max_tilt_deg`` off the board normal, rolled at random, at a random distance (default: the board
    filling 40-90 % of the image width)."""
    W, H = board.size_m
    lo = board.object_points[:, :2].min(axis=0)
    hi = board.object_points[:, :2].max(axis=0)
    centre = np.r_[0.5 * (lo + hi), 0.0]
    if distance_m is None:
        f = camera.K[0, 0]
        d_fill = f * W / camera.width
        distance_m = (d_fill / 0.9, d_fill / 0.4)
    outline = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]], float)
    pad = 0.5 * board.square_m
    outline[:, :2] += np.array([[-pad, -pad], [pad, -pad], [pad, pad], [-pad, pad]])
    views: list[F64] = []
    for _ in range(max_tries):
        if len(views) == n:
            break
        tilt = np.radians(rng.uniform(0.0, max_tilt_deg))
        az = rng.uniform(0.0, 2 * np.pi)
        d = rng.uniform(*distance_m)
        aim = centre + np.r_[rng.uniform(-0.2, 0.2, 2) * (W, H), 0.0]
        eye = aim + d * np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
        roll = rng.uniform(0.0, 2 * np.pi)
        T = look_at(eye, aim, (np.cos(roll), np.sin(roll), 0.0))
        dense = np.concatenate([np.linspace(outline[k], outline[(k + 1) % 4], 20) for k in range(4)])
        uv = camera.project(T, dense)
        inside = (uv[:, 0] > margin_px) & (uv[:, 0] < camera.width - 1 - margin_px)
        inside &= (uv[:, 1] > margin_px) & (uv[:, 1] < camera.height - 1 - margin_px)
        if inside.all():
            views.append(T)
    if len(views) < n:
        raise ValueError(f"found only {len(views)} of {n} views with the whole board in the image")
    return views
