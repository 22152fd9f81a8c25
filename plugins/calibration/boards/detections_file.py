"""The board detections a calibration used, as a file anyone can check the result with:
``detections.json`` in the ``--report`` folder of ``vgr calibrate intrinsics`` and of
``vgr calibrate handeye|robot-world --images ... --board ...`` (and ``RUN.mcap --board``).

Format ``vgr.board_detections/1`` (JSON Schema: plugins/calibration/schemas/board_detections.schema.json)::

    {"format": "vgr.board_detections/1",
     "board": "charuco:9x6:30mm:22mm:DICT_4X4_50",        # the spec, as --board takes it
     "pixel_convention": "opencv",                        # (0, 0) is the centre of the top-left pixel
     "views": [{"name": "im_00.png", "image_size": [640, 480], "method": "...", "ambiguous": false,
                "used": true, "left_out": null,            # or why the calibration left it out
                "ids": [0, 1, ...],                         # the board's corner / feature ids
                "image_points_px": [[u, v], ...],           # where they were found
                "object_points_m": [[x, y, z], ...]}],      # where they are on the board
     "rejected": [{"name": "broken.png", "reason": "not a readable image", "unreadable": true}]}

Views are in the order the calibration saw them (sorted file names, or the recording's order).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from engine.files import replace_text
from plugins.calibration.boards.detect import Detection, Rejection
from plugins.camera.board_spec import BoardSpec

FORMAT = "vgr.board_detections/1"


def detections_document(
    board: BoardSpec,
    views: Sequence[Detection],
    rejected: Sequence[Rejection] = (),
    left_out: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """The ``vgr.board_detections/1`` document of *views* (those whose file name is in *left_out*
    marked unused, with its reason) and the *rejected* images."""
    left_out = {Path(k).name: v for k, v in (left_out or {}).items()}
    return {
        "format": FORMAT,
        "board": board.spec,
        "pixel_convention": "opencv",
        "views": [
            {
                "name": Path(d.name).name,
                "image_size": list(d.image_size),
                "method": d.method,
                "ambiguous": bool(d.ambiguous),
                "used": Path(d.name).name not in left_out,
                "left_out": left_out.get(Path(d.name).name),
                "ids": [int(i) for i in d.ids],
                "image_points_px": d.image_points.tolist(),
                "object_points_m": d.object_points.tolist(),
            }
            for d in views
        ],
        "rejected": [{"name": Path(r.name).name, "reason": r.reason, "unreadable": r.unreadable} for r in rejected],
    }


def write_detections(path: Path, document: dict[str, Any]) -> None:
    """Write *document* to *path* (a report folder's file, under engine.files' rules)."""
    replace_text(path, json.dumps(document, allow_nan=False) + "\n")
