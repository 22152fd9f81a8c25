"""Simulated model-gap campaigns with hidden effects (the tests' and benchmarks/gap.py's ground
truth), the detectability of each effect, and the hidden-effect suite."""
