"""The exit codes of ``vgr calibrate`` for a usable result (engine/exit_codes.py): 0 with verdict
``ok``, 3 with verdict ``warning`` (usable, read the reasons). Tests assert the pair, so a usable
result with the wrong code fails as surely as a wrong verdict."""

USABLE = {(0, "ok"), (3, "warning")}
