"""Generic stages (``stages/``: synthetic sources, rigid transforms, statistics sinks, a trigger),
small helpers any plugin may use, and the demo parts generated in code (workpieces.py)."""
