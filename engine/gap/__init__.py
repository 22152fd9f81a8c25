"""The model-gap workflow core: compare a model with measurements, name the missing effect, add it.

Domain-free: models and candidate effects come in through :mod:`engine.gap.interfaces` (effect
families from plugins via the ``vgr_model_effects`` hook). See ``docs/model_gap.md``.
"""

from .interfaces import (
    Candidate,
    Design,
    EffectFamily,
    Feature,
    FittedEffect,
    GapInputError,
    GapProblem,
    Linearisation,
    Signature,
)
from .selection import SelectionConfig
from .workflow import GapConfig, GapResult, run_gap

__all__ = [
    "Candidate",
    "Design",
    "EffectFamily",
    "Feature",
    "FittedEffect",
    "GapConfig",
    "GapInputError",
    "GapProblem",
    "GapResult",
    "Linearisation",
    "SelectionConfig",
    "Signature",
    "run_gap",
]
