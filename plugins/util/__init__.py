"""Generic stages (synthetic sources, rigid transforms, statistics sinks) and small helpers any plugin may use."""
