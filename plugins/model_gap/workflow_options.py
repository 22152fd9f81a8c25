"""``vgr gap`` option checks shared between its workflows (robot, ``--camera``, ``--depth``) beyond the
selection options (:mod:`.selection_options`): the ranges of the end options (--outlier-alpha,
--min-share, --noise-trust) and the refusal of options that belong to another workflow."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

__all__ = ["check_end_args", "given_options", "refuse_options"]


def check_end_args(args: argparse.Namespace) -> None:
    """ValueError unless --outlier-alpha is in [0, 0.5), --min-share in [0, 1] and --noise-trust >= 1."""
    if not (0 <= args.outlier_alpha < 0.5):
        raise ValueError(f"--outlier-alpha must be in [0, 0.5) (0: no screen), got {args.outlier_alpha}")
    if not (0 <= args.min_share <= 1):
        raise ValueError(f"--min-share must be in [0, 1], got {args.min_share}")
    if not (args.noise_trust >= 1):
        raise ValueError(f"--noise-trust must be >= 1, got {args.noise_trust}")


def given_options(args: argparse.Namespace, names: Sequence[str]) -> list[str]:
    """The flags (``--name``) of *names* set in *args* (not None, False or empty), the ``action``
    (``check``) first when one is given."""
    given = [f"--{name.replace('_', '-')}" for name in names if getattr(args, name, None) not in (None, False, [], ())]
    if getattr(args, "action", None) is not None:
        given.insert(0, str(args.action))
    return given


def refuse_options(args: argparse.Namespace, names: Sequence[str], why: str) -> None:
    """ValueError ``"--a, --b: <why>"`` when any of *names* (or an action) is given: options of
    another workflow, which this one would ignore."""
    given = given_options(args, names)
    if given:
        raise ValueError(f"{', '.join(given)}: {why}")
