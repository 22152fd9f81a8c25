"""Generic stages: synthetic sources, rigid transforms, statistics sinks (demos, tests, glue)."""
