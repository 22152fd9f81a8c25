"""The argument parser of every ``vgr`` verb: argparse, with negative numbers always values.

argparse takes ``-30`` for a value but ``-1e-3`` or ``-470,-80,0`` for an unknown option, and an
option written ``--opt=V`` for one value only: ``--tool-mm -30 20 120`` and ``--tool-mm=-30 20 120``
must both mean the three numbers. :class:`ArgumentParser` (and every sub-command parser made from
it) takes any negative number or comma list of numbers as a value; :func:`split_negative_values`
turns ``--opt=-30`` into ``--opt -30`` before parsing, so the remaining values of a several-value
option follow it as they do without the ``=``.
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Sequence

_NUMBER = r"(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?"
#: a negative number (-30, -0.5, -1e-3) or a comma list of numbers that starts with one (-470,-80,0)
NEGATIVE_VALUE = re.compile(rf"^-{_NUMBER}(,\s*-?{_NUMBER})*$")


class ArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` for which every :data:`NEGATIVE_VALUE` is a value, never an option."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._negative_number_matcher = NEGATIVE_VALUE  # (argparse's own: -30 and -0.5 only)


def add_listen_option(p: argparse.ArgumentParser, default: str) -> None:
    """``--listen ENDPOINT`` (repeatable), ``private`` included; *default* says what is listened on without it."""
    p.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help=f"zenoh listen endpoint (repeatable), e.g. tcp/127.0.0.1:7447, or 'private': a unix socket of the "
        f"run that only this user can open (default: {default})",
    )


def split_negative_values(argv: Sequence[str]) -> list[str]:
    """``--opt=-30`` -> ``--opt``, ``-30``: a long option's negative value given with ``=`` is passed
    as the option's first value, so a several-value option takes the values after it too."""
    out: list[str] = []
    for a in argv:
        name, eq, value = a.partition("=")
        if a.startswith("--") and eq and NEGATIVE_VALUE.match(value):
            out += [name, value]
        else:
            out.append(a)
    return out
