"""Calibration boards described once: the spec string, the board file, and the board's 3-D points.

A board is given on the command line as a spec string or as the path of a board file (YAML/JSON):

* ``chessboard:COLSxROWS:SQUARE`` -- a chessboard of COLS x ROWS **squares** (the printed squares,
  as calib.io and OpenCV's ChArUco count them; OpenCV's chessboard detector is then given the
  (COLS-1) x (ROWS-1) **inner corners**, which are the board's features), e.g.
  ``chessboard:25x18:15mm`` has 24 x 17 inner corners.
* ``charuco:COLSxROWS:SQUARE:MARKER:DICT[:legacy]`` -- a ChArUco board of COLS x ROWS squares, the
  ArUco markers MARKER wide, from any OpenCV predefined dictionary (``DICT_5X5_100``,
  ``DICT_APRILTAG_36h11``, ...); ``legacy`` selects OpenCV's pre-4.6 layout, which older calib.io
  boards with an even number of rows use (the top-left square holds a marker). Partial views work.
* ``circles:COLSxROWS:SPACING[:asymmetric]`` -- a grid of COLS circles per row and ROWS rows;
  SPACING is the distance between the centres of neighbouring circles (symmetric grid). For the
  asymmetric grid it is OpenCV's ``squareSize``: the distance between neighbouring rows, so circles
  within one row are 2 x SPACING apart and every other row is shifted by SPACING.

Lengths carry their unit (``15mm``, ``1.5cm``, ``0.015m``); inside the code they are metres.

Board frame ``target`` (the same for every kind): origin at the bottom-left corner of the board's
grid of squares (chessboard, ChArUco) or at the bottom-left circle's centre (circles), x along the
COLS direction, y along the ROWS direction, **z out of the printed face** (towards a camera that
sees the board), all features at z = 0. "Bottom-left" is fixed by the board itself:

* ChArUco: by the markers (OpenCV's layout, whose top-left corner is the printed image's; OpenCV's
  own frame has y down and z into the board, vgr's is that one turned 180 degrees about x);
* chessboard: the square at the origin is **black**. When COLS + ROWS is odd this names one corner
  of the board; when it is even (both even or both odd, e.g. 8x8 or 9x7) the board looks the same
  turned by 180 degrees and its origin cannot be told from an image: such a board is
  ``ambiguous`` (fine for camera intrinsics, refused for board poses, see :mod:`.detect`);
* circles: an asymmetric grid with an odd number of rows has one orientation; a symmetric grid, or
  an asymmetric one with an even number of rows, is ``ambiguous`` in the same way.

Feature ids: chessboard inner corner ``(i, j)`` (``i`` along x from the left, ``j`` along y from
the bottom) has id ``j * (COLS - 1) + i``; ChArUco corners keep OpenCV's ids; circle ``(i, j)`` (``j``
from the bottom row) has id ``j * COLS + i``.

A board file holds the same fields: ``type`` (chessboard / charuco / circles), ``cols``, ``rows``,
``square_mm`` (or ``square_m``; ``spacing_mm`` for circles), ``marker_mm`` (ChArUco), ``dictionary``,
``legacy``, ``asymmetric``, optionally ``circle_diameter_mm`` (for rendering); or one key ``spec``
holding a spec string.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
BoardKind = Literal["chessboard", "charuco", "circles"]
KINDS: tuple[BoardKind, ...] = ("chessboard", "charuco", "circles")

__all__ = ["KINDS", "BoardKind", "BoardSpec", "BoardSpecError", "load_board", "parse_board"]

_UNITS = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}
_LENGTH = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(mm|cm|m)?\s*$")
_SIZE = re.compile(r"^\s*(\d+)\s*[xX×]\s*(\d+)\s*$")
_MIN_LENGTH_M, _MAX_LENGTH_M = 1e-4, 5.0
_MAX_COUNT = 200

FORMATS = {
    "chessboard": "chessboard:COLSxROWS:SQUARE (squares, e.g. chessboard:25x18:15mm)",
    "charuco": "charuco:COLSxROWS:SQUARE:MARKER:DICT[:legacy] (e.g. charuco:12x9:60mm:45mm:DICT_5X5_100)",
    "circles": "circles:COLSxROWS:SPACING[:asymmetric] (e.g. circles:4x11:20mm:asymmetric)",
}


class BoardSpecError(ValueError):
    """A board spec or board file that does not describe a board; the message says what to write."""


def _usage() -> str:
    return "; ".join(FORMATS.values()) + "; or a board file (.yaml / .json)"


def _length(text: str, what: str) -> float:
    m = _LENGTH.match(text)
    if not m:
        raise BoardSpecError(f"{what} {text!r} is not a length: write a number and its unit, e.g. 15mm")
    if m.group(2) is None:
        raise BoardSpecError(f"{what} {text!r} has no unit: write e.g. {m.group(1)}mm or {m.group(1)}m")
    value = float(m.group(1)) * _UNITS[m.group(2)]
    if not (_MIN_LENGTH_M <= value <= _MAX_LENGTH_M):
        raise BoardSpecError(f"{what} {text!r} = {value:g} m is outside 0.1 mm .. 5 m: a unit slip?")
    return value


def _size(text: str) -> tuple[int, int]:
    m = _SIZE.match(text)
    if not m:
        raise BoardSpecError(f"board size {text!r} is not COLSxROWS (two whole numbers, e.g. 25x18)")
    return int(m.group(1)), int(m.group(2))


def _dictionary_id(name: str) -> tuple[str, int]:
    import cv2

    key = name.strip().upper()
    if not key.startswith("DICT_"):
        key = "DICT_" + key
    names = {n.upper(): n for n in dir(cv2.aruco) if n.startswith("DICT_")}
    if key not in names:
        known = sorted({n.upper() for n in names})
        raise BoardSpecError(f"unknown ArUco dictionary {name!r}; OpenCV has {', '.join(known)}")
    return key, int(getattr(cv2.aruco, names[key]))


@dataclass(frozen=True)
class BoardSpec:
    """One calibration board. Lengths in metres; counts as the module docstring defines them."""

    kind: BoardKind
    cols: int
    rows: int
    square_m: float  # square side (chessboard, ChArUco) or circle spacing (circles)
    marker_m: float | None = None  # ChArUco marker side
    dictionary: str | None = None  # ChArUco: OpenCV predefined dictionary name, upper case
    legacy: bool = False  # ChArUco: OpenCV's pre-4.6 layout
    asymmetric: bool = False  # circles
    circle_diameter_m: float | None = None  # circles: for rendering (default: half the centre distance)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise BoardSpecError(f"unknown board type {self.kind!r}: use {', '.join(KINDS)}")
        for name in ("cols", "rows"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer):
                raise BoardSpecError(f"{name} must be a whole number, got {v!r}")
        least = {"chessboard": 4, "charuco": 3, "circles": 3}[self.kind]
        what = "circles" if self.kind == "circles" else "squares"
        if min(self.cols, self.rows) < least or max(self.cols, self.rows) > _MAX_COUNT:
            extra = " (3x3 inner corners)" if self.kind == "chessboard" else ""
            raise BoardSpecError(
                f"{self.kind} {self.cols}x{self.rows}: needs {least}..{_MAX_COUNT} {what} per side{extra}"
            )
        if not (np.isfinite(self.square_m) and _MIN_LENGTH_M <= self.square_m <= _MAX_LENGTH_M):
            raise BoardSpecError(f"square size {self.square_m!r} m is outside 0.1 mm .. 5 m")
        if self.kind == "charuco":
            if self.marker_m is None or self.dictionary is None:
                raise BoardSpecError(f"a ChArUco board needs a marker size and a dictionary: {FORMATS['charuco']}")
            if not (_MIN_LENGTH_M <= self.marker_m < self.square_m):
                raise BoardSpecError(
                    f"marker {self.marker_m * 1e3:g} mm must be smaller than the square {self.square_m * 1e3:g} mm"
                )
            key, _ = _dictionary_id(self.dictionary)
            object.__setattr__(self, "dictionary", key)
            n_markers = (self.cols * self.rows) // 2
            size = self._dictionary_size()
            if n_markers > size:
                raise BoardSpecError(
                    f"a {self.cols}x{self.rows} ChArUco board has {n_markers} markers but {key} only {size}: "
                    "use a larger dictionary (e.g. ..._250 or ..._1000)"
                )
        elif self.marker_m is not None or self.dictionary is not None or self.legacy:
            raise BoardSpecError(f"marker size, dictionary and legacy belong to ChArUco boards, not {self.kind}")
        if self.kind != "circles" and (self.asymmetric or self.circle_diameter_m is not None):
            raise BoardSpecError("asymmetric and circle diameter belong to circle grids")
        if self.kind == "circles":
            d = self.circle_diameter_m
            pitch = self.square_m * (np.sqrt(2.0) if self.asymmetric else 1.0)  # nearest centres
            if d is not None and not (0 < d < pitch):
                raise BoardSpecError(f"circle diameter {d * 1e3:g} mm must be below the centre distance")

    # ------------------------------------------------------------------ description

    @property
    def spec(self) -> str:
        """The canonical spec string (parse_board(spec) gives this board back)."""
        mm = f"{self.square_m * 1e3:g}mm"
        if self.kind == "chessboard":
            return f"chessboard:{self.cols}x{self.rows}:{mm}"
        if self.kind == "charuco":
            assert self.marker_m is not None
            tail = ":legacy" if self.legacy else ""
            return f"charuco:{self.cols}x{self.rows}:{mm}:{self.marker_m * 1e3:g}mm:{self.dictionary}{tail}"
        return f"circles:{self.cols}x{self.rows}:{mm}" + (":asymmetric" if self.asymmetric else "")

    def describe(self) -> str:
        """One line for people, naming what COLSxROWS counts."""
        sq = f"{self.square_m * 1e3:g} mm"
        if self.kind == "chessboard":
            return (
                f"chessboard of {self.cols}x{self.rows} squares of {sq} ({self.cols - 1}x{self.rows - 1} inner corners)"
            )
        if self.kind == "charuco":
            assert self.marker_m is not None
            return (
                f"ChArUco board of {self.cols}x{self.rows} squares of {sq}, markers {self.marker_m * 1e3:g} mm "
                f"from {self.dictionary}{' (legacy layout)' if self.legacy else ''}"
            )
        grid = "asymmetric" if self.asymmetric else "symmetric"
        return f"{grid} grid of {self.cols}x{self.rows} circles, spacing {sq}"

    # ------------------------------------------------------------------ geometry

    @property
    def grid_shape(self) -> tuple[int, int]:
        """(points per row, rows) of the feature grid: OpenCV's ``patternSize`` for chessboards and
        circles, the inner-corner grid for ChArUco."""
        if self.kind == "circles":
            return self.cols, self.rows
        return self.cols - 1, self.rows - 1

    @property
    def n_features(self) -> int:
        w, h = self.grid_shape
        return w * h

    @property
    def size_m(self) -> tuple[float, float]:
        """Width and height of the pattern (squares' outline; circles: centre span plus a diameter)."""
        if self.kind == "circles":
            d = self.diameter_m
            w = (2 * (self.cols - 1) + 1 if self.asymmetric else self.cols - 1) * self.square_m
            return w + d, (self.rows - 1) * self.square_m + d
        return self.cols * self.square_m, self.rows * self.square_m

    @property
    def diameter_m(self) -> float:
        """Circle diameter (circles only; default half the distance between nearest centres)."""
        if self.circle_diameter_m is not None:
            return self.circle_diameter_m
        return 0.5 * self.square_m * (np.sqrt(2.0) if self.asymmetric else 1.0)

    @cached_property
    def object_points(self) -> F64:
        """(n_features, 3) feature positions in the board frame (m), row ``k`` = feature id ``k``."""
        s = self.square_m
        w, h = self.grid_shape
        if self.kind == "charuco":
            # OpenCV's corner k at ((k % w + 1) s, (k // w + 1) s) (y down, z into the board; in float32
            # there), turned 180 deg about x: y' = ROWS s - y, z' = -z
            k = np.arange(w * h)
            return np.column_stack([(k % w + 1) * s, self.rows * s - (k // w + 1) * s, np.zeros(len(k))])
        i, j = np.meshgrid(np.arange(w), np.arange(h))  # j from the bottom
        i, j = i.ravel(), j.ravel()
        if self.kind == "chessboard":
            x, y = (i + 1) * s, (j + 1) * s
        else:
            # OpenCV's asymmetric grid offsets its odd rows counted from the top (row h-1-j)
            x = (2 * i + ((h - 1 - j) % 2)) * s if self.asymmetric else i * s
            y = j * s
        return np.column_stack([x, y, np.zeros(len(i))]).astype(float)

    @property
    def ambiguous(self) -> bool:
        """True when the board looks the same turned 180 degrees in its plane, so its origin cannot be
        told from an image (chessboard with COLS + ROWS even, symmetric circle grid, asymmetric grid
        with an even number of rows). ChArUco boards never are: the markers name every corner."""
        if self.kind == "chessboard":
            return (self.cols + self.rows) % 2 == 0
        if self.kind == "circles":
            return not self.asymmetric or self.rows % 2 == 0
        return False

    # ------------------------------------------------------------------ OpenCV objects

    def _dictionary_size(self) -> int:
        import cv2

        _, ident = _dictionary_id(self.dictionary or "")
        return int(cv2.aruco.getPredefinedDictionary(ident).bytesList.shape[0])

    def cv_dictionary(self) -> Any:
        """The ``cv2.aruco.Dictionary`` of a ChArUco board."""
        import cv2

        _, ident = _dictionary_id(self.dictionary or "")
        return cv2.aruco.getPredefinedDictionary(ident)

    def cv_board(self) -> Any:
        """The ``cv2.aruco.CharucoBoard`` of a ChArUco board (OpenCV's frame: y down, z into the board)."""
        import cv2

        if self.kind != "charuco":
            raise BoardSpecError(f"a {self.kind} has no ChArUco board")
        board = cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_m, self.marker_m, self.cv_dictionary())
        board.setLegacyPattern(self.legacy)
        return board

    def to_dict(self) -> dict[str, Any]:
        """Board file content (the ``load_board`` format)."""
        d: dict[str, Any] = {"type": self.kind, "cols": self.cols, "rows": self.rows}
        d["spacing_mm" if self.kind == "circles" else "square_mm"] = self.square_m * 1e3
        if self.kind == "charuco":
            d.update(marker_mm=(self.marker_m or 0.0) * 1e3, dictionary=self.dictionary, legacy=self.legacy)
        if self.kind == "circles":
            d["asymmetric"] = self.asymmetric
            if self.circle_diameter_m is not None:
                d["circle_diameter_mm"] = self.circle_diameter_m * 1e3
        return d


# --------------------------------------------------------------------------- parsing


def parse_board(text: str | Path) -> BoardSpec:
    """A board from a spec string (module docstring) or from the path of a board file."""
    if isinstance(text, Path) or (isinstance(text, str) and Path(text).suffix.lower() in (".yaml", ".yml", ".json")):
        return load_board(text)
    if not isinstance(text, str):
        raise BoardSpecError(f"a board spec is a string, got {type(text).__name__}")
    parts = [p.strip() for p in text.strip().split(":")]
    kind = parts[0].lower()
    if kind not in FORMATS:
        raise BoardSpecError(f"board {text!r}: unknown type {parts[0]!r}; write {_usage()}")
    usage = FORMATS[kind]
    try:
        if kind == "chessboard":
            if len(parts) != 3:
                raise BoardSpecError("expected 3 fields")
            cols, rows = _size(parts[1])
            return BoardSpec("chessboard", cols, rows, _length(parts[2], "square size"))
        if kind == "charuco":
            if len(parts) not in (5, 6) or (len(parts) == 6 and parts[5].lower() != "legacy"):
                raise BoardSpecError("expected 5 fields and optionally 'legacy'")
            cols, rows = _size(parts[1])
            sq, marker = _length(parts[2], "square size"), _length(parts[3], "marker size")
            return BoardSpec("charuco", cols, rows, sq, marker, parts[4], legacy=len(parts) == 6)
        if len(parts) not in (3, 4) or (len(parts) == 4 and parts[3].lower() not in ("asymmetric", "symmetric")):
            raise BoardSpecError("expected 3 fields and optionally 'asymmetric'")
        cols, rows = _size(parts[1])
        asym = len(parts) == 4 and parts[3].lower() == "asymmetric"
        return BoardSpec("circles", cols, rows, _length(parts[2], "spacing"), asymmetric=asym)
    except BoardSpecError as exc:
        raise BoardSpecError(f"board {text!r}: {exc}; write {usage}") from None


def _file_length(d: dict[str, Any], name: str, where: str) -> float | None:
    for unit, scale in (("mm", 1e-3), ("m", 1.0)):
        key = f"{name}_{unit}"
        if key in d:
            v = d[key]
            if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
                raise BoardSpecError(f"{where}: {key} must be a number, got {v!r}")
            return float(v) * scale
    return None


def load_board(path: str | Path) -> BoardSpec:
    """A board from a YAML / JSON board file (module docstring)."""
    p = Path(path)
    if not p.is_file():
        raise BoardSpecError(f"board file {p}: no such file")
    try:
        text = p.read_text()
        d = json.loads(text) if p.suffix.lower() == ".json" else _yaml(text)
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise BoardSpecError(f"board file {p}: cannot read it ({exc})") from None
    if not isinstance(d, dict):
        raise BoardSpecError(f"board file {p}: expected a mapping of board fields, got {type(d).__name__}")
    if "spec" in d:
        if set(d) != {"spec"} or not isinstance(d["spec"], str):
            raise BoardSpecError(f"board file {p}: 'spec' (a spec string) stands alone")
        return parse_board(d["spec"])
    where = f"board file {p}"
    known = {"type", "cols", "rows", "square_mm", "square_m", "spacing_mm", "spacing_m", "marker_mm", "marker_m",
             "dictionary", "legacy", "asymmetric", "circle_diameter_mm", "circle_diameter_m"}  # fmt: skip
    unknown = sorted(set(d) - known)
    if unknown:
        raise BoardSpecError(f"{where}: unknown field(s) {', '.join(unknown)}; fields are {', '.join(sorted(known))}")
    kind = str(d.get("type", "")).lower()
    if kind not in KINDS:
        raise BoardSpecError(f"{where}: 'type' must be one of {', '.join(KINDS)}, got {d.get('type')!r}")
    size = _file_length(d, "spacing" if kind == "circles" else "square", where)
    if size is None:
        raise BoardSpecError(f"{where}: give {'spacing_mm' if kind == 'circles' else 'square_mm'} (or ..._m)")
    for key in ("legacy", "asymmetric"):
        if key in d and not isinstance(d[key], bool):
            raise BoardSpecError(f"{where}: {key} must be true or false, got {d[key]!r}")
    try:
        return BoardSpec(
            kind,  # type: ignore[arg-type]
            d.get("cols"),  # type: ignore[arg-type]
            d.get("rows"),  # type: ignore[arg-type]
            size,
            marker_m=_file_length(d, "marker", where),
            dictionary=d.get("dictionary"),
            legacy=bool(d.get("legacy", False)),
            asymmetric=bool(d.get("asymmetric", False)),
            circle_diameter_m=_file_length(d, "circle_diameter", where),
        )
    except BoardSpecError as exc:
        raise BoardSpecError(f"{where}: {exc}") from None


def _yaml(text: str) -> Any:
    import yaml

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(str(exc).replace("\n", " ")) from None
