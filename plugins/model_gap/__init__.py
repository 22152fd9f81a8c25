"""The model-gap workflow for robot cells: ``vgr gap``, the ``model_gap`` stage, the catalog.

The statistics and the loop live in :mod:`plugins.model_gap.core` (no robot knowledge); this package supplies
the robot-kinematics problem (:mod:`.problem`), the effect families registered through the
``vgr_model_effects`` hook (:mod:`.effects`), data readers (:mod:`.data`, :mod:`.recordings`,
:mod:`.inputs`) and the front ends (``vgr gap``, the stages in ``stages/``). The hidden-effect
simulator of the tests and benchmark is plugins.sim.model_gap.

The names below are imported lazily: ``vgr`` imports :mod:`.cli` to build its parser on every start,
and that must not pull in scipy.stats and the kinematics (seconds on a loaded machine).
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "analyse_gap": "analyse",
    "families_from_registry": "families",
    "load_gap_model": "stored_model",
    "GapData": "data",
    "GapDataError": "data",
    "load_gap_data": "inputs",
    "pair_streams": "recordings",
    "read_gap_csv": "data",
    "read_gap_mcap": "recordings",
    "write_gap_csv": "data",
    "FAMILIES": "effects",
    "builtin_families": "effects",
    "KinematicGapProblem": "problem",
    "ProblemConfig": "problem",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)
