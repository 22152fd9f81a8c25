"""Finding a calibration board in images: features with sub-pixel positions, ids and 3-D points.

What OpenCV does (and is not rewritten here): ``cv2.findChessboardCornersSB`` (sub-pixel by its own
fit; tried first, then with normalisation and the exhaustive search), the classic
``cv2.findChessboardCorners`` + ``cv2.cornerSubPix`` as the fallback, ``cv2.aruco.CharucoDetector``
(markers, interpolated and refined corners; partial views), ``cv2.findCirclesGrid`` with a blob
detector sized for the image. What is ours: reading any png / jpg / bmp / tif (grey, colour, alpha,
16 bit) into 8-bit grey without crashing on a corrupt file, and putting a grid's features into the
board's own numbering (:mod:`.spec`), which OpenCV leaves open:

* a chessboard or circle grid comes back from OpenCV in one of the grid's symmetric orderings
  (reversed, mirrored, or turned 90 degrees on a square grid). vgr keeps the orderings whose
  homography sees the board's front (z towards the camera; a mirrored ordering would put the camera
  behind the board) and fits the board's geometry (an asymmetric circle grid fits in one ordering
  only), and for chessboards the one in which the origin square is black (the squares' grey levels
  decide). When more than one ordering remains (:attr:`BoardSpec.ambiguous`: a chessboard with
  COLS + ROWS even, a symmetric circle grid), the detection is marked ``ambiguous``: its 2-D points
  are right for intrinsics, but its origin may be any of the remaining corners, so a board pose from
  it is refused (:mod:`.board_pose`).

Every image gives either a :class:`Detection` or a :class:`Rejection` with the reason (unreadable,
not an image, board not found, too few ChArUco corners, different image size); nothing raises.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from plugins.camera.board_spec import BoardSpec

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

__all__ = [
    "IMAGE_SUFFIXES",
    "BoardNotFoundError",
    "Detection",
    "Detections",
    "ImageReadError",
    "Rejection",
    "detect_board",
    "detect_images",
    "image_files",
    "read_gray",
    "to_gray",
]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
MIN_CHARUCO_CORNERS = 6  # PnP and calibrateCamera need >= 4 off one line; 6 leaves a little redundancy
SB_FLAGS = 0


class ImageReadError(ValueError):
    """An image file that cannot be read (missing, not an image, corrupt, unsupported type)."""


class BoardNotFoundError(ValueError):
    """The board is not (completely enough) in an image; the message says what was seen."""


@dataclass(frozen=True, eq=False)
class Detection:
    """The board's features found in one image: ``ids`` (n,), ``image_points`` (n, 2) in pixels
    (OpenCV's convention: the centre of the top-left pixel is (0, 0)), ``object_points`` (n, 3) in
    the board frame (m). ``ambiguous``: the board's origin could not be told (see the module)."""

    name: str
    image_size: tuple[int, int]  # (width, height)
    ids: NDArray[np.int64]
    image_points: F64
    object_points: F64
    method: str
    ambiguous: bool = False

    @property
    def n(self) -> int:
        return len(self.ids)


@dataclass(frozen=True)
class Rejection:
    """An image that gave no usable detection, and why."""

    name: str
    reason: str
    unreadable: bool = False  # the file could not be read as an image (vs. read, board not found)


@dataclass
class Detections:
    """The outcome over a set of images, in the order given."""

    board: BoardSpec
    found: list[Detection] = field(default_factory=list)
    rejected: list[Rejection] = field(default_factory=list)

    @property
    def image_size(self) -> tuple[int, int] | None:
        return self.found[0].image_size if self.found else None

    def summary(self) -> str:
        n = len(self.found) + len(self.rejected)
        lines = [f"board found in {len(self.found)} of {n} image(s) ({self.board.describe()})"]
        lines += [f"  {r.name}: {r.reason}" for r in self.rejected]
        return "\n".join(lines)


# --------------------------------------------------------------------------- images


def to_gray(image: NDArray[Any]) -> U8:
    """8-bit grey of a grey / BGR / BGRA image of any integer or float depth (16-bit and float
    images are scaled by their own range)."""
    import cv2

    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (3, 4)) or min(a.shape[:2]) < 8:
        raise ImageReadError(f"not an image of grey or colour pixels (array shape {a.shape})")
    if a.dtype != np.uint8:
        f = a.astype(np.float64)
        if not np.all(np.isfinite(f)):
            f = np.nan_to_num(f, nan=0.0, posinf=0.0, neginf=0.0)
        if a.dtype == np.uint16:
            hi = max(float(f.max()), 1.0)
            f = f * (255.0 / hi)
        else:
            lo, hi = float(f.min()), float(f.max())
            f = (f - lo) * (255.0 / (hi - lo) if hi > lo else 0.0)
        a = np.clip(np.rint(f), 0, 255).astype(np.uint8)
    if a.ndim == 3:
        a = cv2.cvtColor(a, cv2.COLOR_BGRA2GRAY if a.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    return np.ascontiguousarray(a)


def read_gray(path: str | Path) -> U8:
    """An image file as 8-bit grey; :class:`ImageReadError` says why it cannot be read."""
    import cv2

    p = Path(path)
    if not p.is_file():
        raise ImageReadError("no such file" if not p.exists() else "not a file")
    if p.suffix.lower() not in IMAGE_SUFFIXES:
        raise ImageReadError(f"not an image file type vgr reads ({', '.join(IMAGE_SUFFIXES)})")
    try:
        buf = np.fromfile(p, dtype=np.uint8)  # imdecode: no libpng/ libjpeg output on the console
    except OSError as exc:
        raise ImageReadError(f"cannot read the file ({exc.strerror or exc})") from None
    if buf.size == 0:
        raise ImageReadError("empty file")
    image = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ImageReadError("not a readable image (corrupt or truncated?)")
    return to_gray(image)


# --------------------------------------------------------------------------- detectors


def _chessboard(gray: U8, board: BoardSpec) -> tuple[F64, str]:
    import cv2

    pattern = board.grid_shape
    for flags in (SB_FLAGS, cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE):
        ok, corners = cv2.findChessboardCornersSB(gray, pattern, flags=flags)
        if ok:
            return corners.reshape(-1, 2).astype(float), "findChessboardCornersSB"
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    ok, corners = cv2.findChessboardCorners(gray, pattern, flags=flags)
    if not ok:
        raise BoardNotFoundError(
            f"no chessboard of {pattern[0]}x{pattern[1]} inner corners found (the whole board must be "
            "in view; is COLSxROWS the number of squares?)"
        )
    pts = corners.reshape(-1, 2).astype(np.float32)
    half = int(np.clip(0.4 * _min_spacing(pts, pattern), 2, 11))
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 1e-3)
    pts = cv2.cornerSubPix(gray, pts.reshape(-1, 1, 2), (half, half), (-1, -1), criteria)
    return pts.reshape(-1, 2).astype(float), "findChessboardCorners+cornerSubPix"


def _min_spacing(pts: NDArray[Any], pattern: tuple[int, int]) -> float:
    g = np.asarray(pts, dtype=float).reshape(pattern[1], pattern[0], 2)
    d = [np.linalg.norm(np.diff(g, axis=1), axis=2).min(), np.linalg.norm(np.diff(g, axis=0), axis=2).min()]
    return float(min(d))


def _circles(gray: U8, board: BoardSpec) -> tuple[F64, str]:
    import cv2

    params = cv2.SimpleBlobDetector_Params()
    params.minArea = 8.0
    params.maxArea = float(gray.size) / 8.0
    params.minDistBetweenBlobs = 2.0
    detector = cv2.SimpleBlobDetector_create(params)
    grid = cv2.CALIB_CB_ASYMMETRIC_GRID if board.asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
    pattern = board.grid_shape
    for flags in (grid, grid | cv2.CALIB_CB_CLUSTERING):
        ok, centres = cv2.findCirclesGrid(gray, pattern, flags=flags, blobDetector=detector)
        if ok:
            return centres.reshape(-1, 2).astype(float), "findCirclesGrid"
    raise BoardNotFoundError(
        f"no {'asymmetric' if board.asymmetric else 'symmetric'} grid of {pattern[0]}x{pattern[1]} circles found "
        "(the whole grid must be in view, dark circles on a light ground)"
    )


def _charuco(gray: U8, board: BoardSpec) -> tuple[NDArray[np.int64], F64, str]:
    import cv2

    cv_board = board.cv_board()
    params = cv2.aruco.CharucoParameters()
    params.tryRefineMarkers = True
    detector = cv2.aruco.CharucoDetector(cv_board, params)
    corners, ids, _marker_corners, marker_ids = detector.detectBoard(gray)
    n_markers = 0 if marker_ids is None else len(marker_ids)
    n = 0 if ids is None else len(ids)
    if n < MIN_CHARUCO_CORNERS:
        if n_markers == 0:
            raise BoardNotFoundError(f"no {board.dictionary} marker found (wrong dictionary, or no board in view)")
        board_ids = set(np.asarray(cv_board.getIds()).ravel().tolist())
        seen = set(np.asarray(marker_ids).ravel().tolist())
        hint = ""
        if not seen & board_ids:
            hint = f": markers {sorted(seen)[:6]} are not this board's (wrong board size or dictionary?)"
        elif n == 0:
            hint = ": markers but no corners between them (try ':legacy' for an older board, or check the sizes)"
        raise BoardNotFoundError(
            f"ChArUco: {n_markers} marker(s), {n} corner(s); need at least {MIN_CHARUCO_CORNERS} corners{hint}"
        )
    return np.asarray(ids, dtype=np.int64).ravel(), np.asarray(corners, dtype=float).reshape(-1, 2), "CharucoDetector"


# --------------------------------------------------------------------------- grid orientation


def _fit_homography(obj_xy: F64, img: F64) -> tuple[F64, float]:
    import cv2

    H, _ = cv2.findHomography(obj_xy, img, 0)
    if H is None:
        return np.eye(3), np.inf
    p = np.column_stack([obj_xy, np.ones(len(obj_xy))]) @ H.T
    proj = p[:, :2] / p[:, 2:3]
    return H, float(np.sqrt(np.mean(np.sum((proj - img) ** 2, axis=1))))


def _jacobian_det(H: F64, xy: F64) -> float:
    """det d(u, v)/d(x, y) of the homography at board point ``xy``: negative when the camera sees
    the board's front (z out of the board towards the camera; image v points down)."""
    x, y = xy
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    u = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w
    v = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w
    J = np.array(
        [
            [(H[0, 0] - u * H[2, 0]) / w, (H[0, 1] - u * H[2, 1]) / w],
            [(H[1, 0] - v * H[2, 0]) / w, (H[1, 1] - v * H[2, 1]) / w],
        ]
    )
    return float(np.linalg.det(J))


def _sample(gray: U8, pts: F64) -> F64:
    import cv2

    m = np.asarray(pts, dtype=np.float32).reshape(-1, 1, 2)
    out = cv2.remap(gray, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1).astype(float)


def _colour_score(gray: U8, G: F64) -> float:
    """(mean grey of the squares that should be white - of those that should be black) / spread,
    for a chessboard corner grid ``G[j, i]`` in the board's numbering."""
    centres = 0.25 * (G[:-1, :-1] + G[1:, :-1] + G[:-1, 1:] + G[1:, 1:])
    j, i = np.meshgrid(np.arange(centres.shape[0]), np.arange(centres.shape[1]), indexing="ij")
    black = ((i + j) % 2 == 0).ravel()  # square (i+1, j+1) is black iff i + j is even
    values = _sample(gray, centres.reshape(-1, 2))
    spread = float(np.percentile(values, 95) - np.percentile(values, 5))
    if spread <= 0 or black.all() or not black.any():
        return 0.0
    return float((values[~black].mean() - values[black].mean()) / spread)


def _orient_grid(gray: U8, board: BoardSpec, pts: F64) -> tuple[F64, bool]:
    """OpenCV's row-major grid points in the board's numbering (module docstring); returns the
    points ordered by feature id and whether the orientation stayed ambiguous."""
    w, h = board.grid_shape
    G0 = pts.reshape(h, w, 2)[::-1]  # OpenCV's first row is the top one; ids count from the bottom
    cands = [G0, G0[::-1], G0[:, ::-1], G0[::-1, ::-1]]
    if w == h:
        T = np.transpose(G0, (1, 0, 2))
        cands += [T, T[::-1], T[:, ::-1], T[::-1, ::-1]]
    obj = board.object_points[:, :2]
    centre = obj.mean(axis=0)
    fits = []
    for G in cands:
        H, rms = _fit_homography(obj, G.reshape(-1, 2))
        fits.append((rms, _jacobian_det(H, centre) < 0))
    front = [k for k, (_, ok) in enumerate(fits) if ok]
    if not front:
        raise BoardNotFoundError("the grid's features do not fit the board (none of its orderings is a view of it)")
    best = min(fits[k][0] for k in front)
    keep = [k for k in front if fits[k][0] <= 2.0 * best + 1.0]
    if board.kind == "chessboard" and len(keep) > 1:
        scores = {k: _colour_score(gray, cands[k]) for k in keep}
        light = [k for k in keep if scores[k] > 0.3]
        keep = light or keep
    return cands[keep[0]].reshape(-1, 2).copy(), len(keep) > 1


# --------------------------------------------------------------------------- public


def detect_board(image: NDArray[Any], board: BoardSpec, name: str = "image") -> Detection:
    """The board in one image (array: grey, BGR or BGRA); :class:`BoardNotFoundError` says why not."""
    gray = to_gray(image)
    size = (int(gray.shape[1]), int(gray.shape[0]))
    if board.kind == "charuco":
        ids, pts, method = _charuco(gray, board)
        obj = board.object_points[ids]
        if np.linalg.matrix_rank(obj[:, :2] - obj[:, :2].mean(axis=0), tol=1e-9) < 2:
            raise BoardNotFoundError(f"ChArUco: the {len(ids)} corners seen lie on one line (a pose needs a 2-D patch)")
        return Detection(name, size, ids, pts, obj, method)
    pts, method = _chessboard(gray, board) if board.kind == "chessboard" else _circles(gray, board)
    ordered, ambiguous = _orient_grid(gray, board, pts)
    ids = np.arange(board.n_features, dtype=np.int64)
    return Detection(name, size, ids, ordered, board.object_points.copy(), method, ambiguous)


def _one(path: Path, board: BoardSpec) -> Detection | Rejection:
    name = str(path)
    try:
        gray = read_gray(path)
    except ImageReadError as exc:
        return Rejection(name, str(exc), unreadable=True)
    try:
        return detect_board(gray, board, name)
    except (ImageReadError, BoardNotFoundError) as exc:
        return Rejection(name, str(exc))
    except Exception as exc:  # an OpenCV error on a strange image must not end the whole set
        return Rejection(name, f"detection failed ({type(exc).__name__}: {str(exc).strip().splitlines()[-1]})")


def image_files(paths: Iterable[str | Path]) -> list[Path]:
    """The paths as given, a folder replaced by its image files (sorted by name)."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            out += sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() in IMAGE_SUFFIXES)
        else:
            out.append(p)
    return out


def detect_images(paths: Iterable[str | Path], board: BoardSpec, *, workers: int | None = None) -> Detections:
    """The board in every image file (a folder: its images), in order (images are independent;
    ``workers`` threads, default the CPU count: OpenCV releases the GIL). Images of another size than
    the first detected one are rejected (one camera, one resolution)."""
    files: Sequence[Path] = image_files(paths)
    n_workers = max(1, min(len(files), workers or os.cpu_count() or 1))
    if n_workers == 1:
        outcomes = [_one(p, board) for p in files]
    else:
        with ThreadPoolExecutor(n_workers) as pool:
            outcomes = list(pool.map(lambda p: _one(p, board), files))
    result = Detections(board)
    for o in outcomes:
        if isinstance(o, Detection):
            size = result.image_size
            if size is not None and o.image_size != size:
                w, h = o.image_size
                result.rejected.append(Rejection(o.name, f"image size {w}x{h} differs from {size[0]}x{size[1]}"))
            else:
                result.found.append(o)
        else:
            result.rejected.append(o)
    return result
