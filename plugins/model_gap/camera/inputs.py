"""What ``vgr gap --camera`` reads: board images (files or folders) or a detections file, and the board.

``--camera`` takes image files, folders of images (their png / jpg / bmp / tif files, sorted by
name), or one ``detections.json`` (format ``vgr.board_detections/1``, as ``vgr calibrate intrinsics
--report`` writes it: the corners are taken as they are, no image is read). ``--board`` is a board
spec or board file (:func:`plugins.camera.board_spec.parse_board`). Every refusal is a
:class:`CameraGapInputError` (a ValueError: exit code 2, and ``vgr.invalid/1`` with ``--json``) that
says which input and what to do.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from plugins.calibration.boards.detect import IMAGE_SUFFIXES, Detection, Detections, Rejection, detect_images
from plugins.calibration.boards.detections_file import FORMAT as DETECTIONS_FORMAT
from plugins.camera.board_spec import BoardSpec, parse_board

__all__ = ["CameraGapInputError", "load_views"]


class CameraGapInputError(ValueError):
    """Input the camera gap cannot use; the message says which and what to do."""


def _board(text: str) -> BoardSpec:
    if not text or not str(text).strip():
        raise CameraGapInputError("--board is empty: give a board spec (e.g. chessboard:25x18:15mm) or a board file")
    try:
        return parse_board(text)
    except ValueError as exc:
        raise CameraGapInputError(f"--board {text!r}: {exc}") from None


def _detections_file(path: Path, board: BoardSpec) -> Detections:
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CameraGapInputError(f"{path}: not a readable detections file ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != DETECTIONS_FORMAT:
        raise CameraGapInputError(f"{path}: not a {DETECTIONS_FORMAT} document (vgr calibrate intrinsics --report)")
    out = Detections(board)
    try:
        for v in doc["views"]:
            ids = np.asarray(v["ids"], dtype=np.int64)
            img = np.asarray(v["image_points_px"], dtype=float).reshape(-1, 2)
            obj = np.asarray(v["object_points_m"], dtype=float).reshape(-1, 3)
            size = (int(v["image_size"][0]), int(v["image_size"][1]))
            if not (len(ids) == len(img) == len(obj)) or not np.all(np.isfinite(img)) or not np.all(np.isfinite(obj)):
                raise ValueError(
                    f"view {v.get('name')!r}: ids, image and object points differ in length or are not finite"
                )
            out.found.append(Detection(str(v["name"]), size, ids, img, obj, str(v.get("method", "file"))))
        out.rejected += [Rejection(str(r["name"]), str(r["reason"])) for r in doc.get("rejected", [])]
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise CameraGapInputError(f"{path}: a view is malformed ({exc})") from None
    if doc.get("board") and parse_board(doc["board"]).spec != board.spec:
        raise CameraGapInputError(f"{path}: detected with board {doc['board']!r}, not the --board {board.spec!r}")
    if len({d.image_size for d in out.found}) > 1:
        raise CameraGapInputError(f"{path}: views of different image sizes (one camera, one resolution)")
    return out


def _image_paths(paths: Sequence[str]) -> list[Path]:
    files: list[Path] = []
    for text in paths:
        p = Path(text)
        if not p.exists():
            raise CameraGapInputError(f"--camera {text}: no such file or folder")
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise CameraGapInputError(f"--camera {text}: the folder holds no images ({', '.join(IMAGE_SUFFIXES)})")
            files += found
        else:
            files.append(p)
    return files


def load_views(camera: Sequence[str], board_text: str) -> Detections:
    """The board detections of the ``--camera`` inputs (module docstring); refusals raise
    :class:`CameraGapInputError`."""
    board = _board(board_text)
    if not camera:
        raise CameraGapInputError("--camera needs images, a folder of images or a detections.json")
    if len(camera) == 1 and Path(camera[0]).suffix.lower() == ".json":
        path = Path(camera[0])
        if not path.is_file():
            raise CameraGapInputError(f"--camera {camera[0]}: no such file")
        return _detections_file(path, board)
    files = _image_paths(camera)
    bad = [f for f in files if f.suffix.lower() not in IMAGE_SUFFIXES]
    if bad:
        raise CameraGapInputError(f"--camera {bad[0]}: not an image file type vgr reads ({', '.join(IMAGE_SUFFIXES)})")
    dets = detect_images(files, board)
    if not dets.found:
        first = "; ".join(f"{Path(r.name).name}: {r.reason}" for r in dets.rejected[:3])
        raise CameraGapInputError(f"the board {board.spec} was found in none of the {len(files)} image(s) ({first})")
    return dets
