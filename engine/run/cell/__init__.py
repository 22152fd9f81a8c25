"""The cell service: a recipe hosted as a long-running service that a robot controller drives.

``vgr serve RECIPE`` (engine.cli.serve) starts the recipe's stages once and keeps them up; every request
a controller sends runs one job (a *cycle*) through the same stages. The parts, one job each:

* engine.run.cell.codes      the one status-code table of every reply;
* engine.run.cell.protocol   the controller API: commands, request and reply documents, their checks;
* engine.run.cell.settings   the recipe's ``serve:`` block and its checks against the graph;
* engine.run.cell.service    the service: zenoh queryables, cycles, idempotent request ids, busy,
                             status, reload, stop;
* engine.recording.cycle_files     rolling per-cycle recordings with their retention limits;
* engine.run.cell.takt       cycle-time figures (p50 / p99 and their split);
* engine.run.cell.client     a small client for controllers written in Python (``vgr call`` uses it).

What a job does (capture, match, a correction in the robot's base frame) is a stage's business:
the service knows only that a command is answered by a stage's service taking a
:class:`~engine.messages.Request` and replying a :class:`~engine.messages.CellReply`
(plugins.actions.stages.cell_locator is vgr's own). docs/cell_service.md is the user's guide.
"""
