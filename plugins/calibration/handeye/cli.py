"""Former command-line front end of the hand-eye library, now ``vgr calibrate handeye|robot-world``.

Kept so that ``python -m plugins.calibration.handeye.cli DATA [--setup ...] [--kind robot_world] [--mm]
[--robot-noise DEG MM] [--camera-noise DEG MM] [--loss huber] [--json OUT]`` keeps working: it
forwards to :mod:`plugins.calibration.cli` (same options, same exit codes: 0 usable, 1
degenerate/failed, 2 bad input).
"""

from __future__ import annotations

import sys

from engine.exit_codes import ExitCode

__all__ = ["main"]

_KINDS = {"hand_eye": "handeye", "robot_world": "robot-world"}


def main(argv: list[str] | None = None) -> int:
    from plugins.calibration.cli import main as calibrate_main

    args = list(sys.argv[1:] if argv is None else argv)
    kind = "handeye"
    if "--kind" in args:
        i = args.index("--kind")
        if i + 1 >= len(args) or args[i + 1] not in _KINDS:
            print(f"bad input: --kind must be one of {list(_KINDS)}", file=sys.stderr)
            return ExitCode.INVALID
        kind = _KINDS[args[i + 1]]
        del args[i : i + 2]
    return calibrate_main([kind, *args])


if __name__ == "__main__":
    raise SystemExit(main())
