"""The model-gap workflow core: compare a model with measurements, name the missing effect, add it.

Domain-free: models and candidate effects come in through :mod:`plugins.model_gap.core.interfaces` (effect
families from plugins via the ``vgr_model_effects`` hook). See ``docs/model_gap.md``.
"""

from plugins.model_gap.core.interfaces import (
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
from plugins.model_gap.core.selection import SelectionConfig
from plugins.model_gap.core.workflow import GapConfig, GapResult, run_gap

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
