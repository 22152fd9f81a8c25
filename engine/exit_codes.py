"""The one exit-code table of every ``vgr`` verb, so a cell controller or a script can act on a code
without knowing which verb it ran (README, *Exit codes*). ``--json`` output carries the same number
as ``exit_code``.

====  ===============  ================================================================================
code  name             meaning
====  ===============  ================================================================================
0     ``OK``           the job was done and its result may be used as it is
1     ``NOT_OK``       the job ran to its end and its outcome is no: a dock, move or step refused (an
                       alarm), a calibration that failed its checks, a model gap left unexplained, a
                       replay whose outputs differ, nothing found where something was asked for
2     ``INVALID``      invalid input or usage: refused before anything ran (a recipe, a file, an option)
3     ``REVIEW``       a qualified ok that needs a human look: a calibration usable with a warning, a
                       gap explained by one of several effects that fit equally well
4     ``FAILED``       a fault: a stage failed, a device or a peer was lost, a recording could not be
                       completed. Told apart from 1 on purpose: 1 is about the part or the data (take
                       the next part, measure again), 4 is about the cell (call maintenance)
130   ``INTERRUPTED``  Ctrl-C, SIGTERM or a stop request; robot motion was halted first
====  ===============  ================================================================================

A leaf module: the run summary, every CLI verb and plugins' verbs import it; it imports nothing.
"""

from __future__ import annotations

from enum import IntEnum


class ExitCode(IntEnum):
    OK = 0
    NOT_OK = 1
    INVALID = 2
    REVIEW = 3
    FAILED = 4
    INTERRUPTED = 130


#: the exit code of a run's (and a replay's) outcome name
OUTCOME_EXIT_CODES: dict[str, ExitCode] = {
    "ok": ExitCode.OK,
    "refused": ExitCode.NOT_OK,
    "different": ExitCode.NOT_OK,
    "failed": ExitCode.FAILED,
    "interrupted": ExitCode.INTERRUPTED,
}


#: the table in one line, for every verb's ``--help``
HELP_EPILOG = (
    "exit codes (the same for every verb): 0 ok; 1 the outcome is no (refused, alarm, failed checks, "
    "a gap left, replay differs); 2 invalid input or usage; 3 ok that needs a human look; 4 a fault "
    "(a stage failed, a device or peer lost); 130 interrupted, motion halted first. README: Exit codes."
)
