"""The model-gap workflow for robot cells (issue 8): ``vgr gap``, the ``model_gap`` stage, the catalog.

The statistics and the loop live in :mod:`engine.gap` (no robot knowledge); this package supplies
the robot-kinematics problem (:mod:`.problem`), the effect families registered through the
``vgr_model_effects`` hook (:mod:`.effects`), data readers (:mod:`.data`), the hidden-effect
simulator of the tests and benchmark (:mod:`.simulate`) and the front ends.
"""

from .analyse import analyse_gap, families_from_registry, load_gap_model
from .data import GapData, GapDataError, load_gap_data, read_gap_csv, read_gap_mcap, write_gap_csv
from .effects import FAMILIES, builtin_families
from .problem import KinematicGapProblem, ProblemConfig

__all__ = [
    "FAMILIES",
    "GapData",
    "GapDataError",
    "KinematicGapProblem",
    "ProblemConfig",
    "analyse_gap",
    "builtin_families",
    "families_from_registry",
    "load_gap_data",
    "load_gap_model",
    "read_gap_csv",
    "read_gap_mcap",
    "write_gap_csv",
]
