"""The selection options the camera and depth gap workflows share (alpha, alpha_tie, folds, seed,
max_effects): their config fields and defaults (:class:`SelectionOptions`, the base of
``CameraGapConfig`` and ``DepthGapConfig``) and their ranges, checked for a config and for
``vgr gap``'s flags (--alpha, --folds, --max-effects; the robot workflow's too)."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

__all__ = ["SelectionOptions", "check_alpha_arg", "check_selection", "check_selection_args"]


def check_selection(alpha: float, alpha_tie: float, folds: int, max_effects: int) -> None:
    """ValueError unless alpha and alpha_tie are in (0, 0.5), folds >= 2 and max_effects >= 0 (a config)."""
    if not (0.0 < alpha < 0.5) or not (0.0 < alpha_tie < 0.5):
        raise ValueError(f"alpha and alpha_tie must be in (0, 0.5), got {alpha}, {alpha_tie}")
    if folds < 2:
        raise ValueError(f"folds must be >= 2, got {folds}")
    if max_effects < 0:
        raise ValueError(f"max_effects must be >= 0, got {max_effects}")


@dataclass(frozen=True)
class SelectionOptions:
    """Family-wise level per round, the tie level, cross-validation folds, their seed, the effect limit
    (checked on construction: :func:`check_selection`)."""

    alpha: float = 1e-3
    alpha_tie: float = 0.01
    folds: int = 5
    seed: int = 0
    max_effects: int = 4

    def __post_init__(self) -> None:
        check_selection(self.alpha, self.alpha_tie, self.folds, self.max_effects)


def check_alpha_arg(alpha: float) -> None:
    """ValueError unless ``--alpha`` is in (0, 0.5)."""
    if not (0 < alpha < 0.5):
        raise ValueError(f"--alpha must be in (0, 0.5), got {alpha}")


def check_selection_args(args: argparse.Namespace) -> None:
    """ValueError unless --alpha is in (0, 0.5), --folds >= 2 and --max-effects >= 0."""
    check_alpha_arg(args.alpha)
    if args.folds < 2:
        raise ValueError(f"--folds must be >= 2, got {args.folds}")
    if args.max_effects < 0:
        raise ValueError("--max-effects must be >= 0")
