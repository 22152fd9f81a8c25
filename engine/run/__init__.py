"""A run's lifetime: the runner (processes, start, stop, halting devices first), each stage's
runtime and its ports (output, remote input, service), the stage host protocols they reach their
runtime through, membership of the run's processes, the run summary with its outcome, and Ctrl-C.

Layer: may import the engine's top level, messages, recipe, security and transport.
"""
