"""The verdict -> exit code table of every model-gap workflow (robot ``vgr gap``, ``--camera``,
``--depth``): the one place that says which verdict exits how (engine.exit_codes)."""

from __future__ import annotations

from engine.exit_codes import ExitCode

__all__ = ["VERDICT_EXIT_CODES"]

#: the exit code of each workflow verdict
VERDICT_EXIT_CODES = {
    "no_gap": ExitCode.OK,
    "explained": ExitCode.OK,
    "explained_up_to_tie": ExitCode.REVIEW,
    "unexplained": ExitCode.NOT_OK,
}
