"""After the run is told to stop (Ctrl-C, a failure, a stop request) no stage sends a new service
request: a data-collection campaign commands no robot move past the stop."""

from __future__ import annotations

import pytest
from recipe_helpers import graph_from

from engine.runner import Observer, Runner

pytestmark = pytest.mark.timeout(120)

RECIPE = """
vgr: 1
name: campaign
seed: 3
clock: sim
stages:
  robot: {type: sim_robot, params: {model: ur5e}}
  tracker: {type: sim_tracker, uses: {robot: robot.truth}}
  start: {type: trigger, params: {count: 1}}
  campaign:
    type: measurement_campaign
    inputs: {trigger: start.out}
    uses: {robot: robot.move, tracker: tracker.sample}
    params: {n_poses: 50}
"""


class StopAfterMoves(Observer):
    """Stops the run (as Ctrl-C does) once the campaign's robot has answered *n* moves."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.moves = 0
        self.runner: Runner | None = None

    def on_service(self, call) -> None:
        if call.stage == "campaign" and call.client == "robot":
            self.moves += 1
            if self.moves == self.n:
                assert self.runner is not None
                self.runner.stop("interrupted (Ctrl-C)")


def test_no_robot_move_is_sent_after_the_stop():
    obs = StopAfterMoves(3)
    runner = Runner(graph_from(RECIPE), observers=[obs])
    obs.runner = runner
    summary = runner.run()
    assert summary.outcome == "interrupted" and summary.exit_code == 130
    assert obs.moves == 3  # the 4th move was never sent (50 were planned)
    # the refused request ends the stage quietly: no error, no traceback, the stop is what happened
    assert not [e for e in summary.events if e.level == "error"], summary.events
    assert not [s for s in summary.stages if s.state == "failed"]


def test_an_early_stop_halts_the_device_stages_first_and_a_normal_end_does_not(monkeypatch):
    from plugins.sim.stages.robot import SimRobot

    order: list[str] = []
    monkeypatch.setattr(SimRobot, "halt", lambda self: order.append("halt"), raising=False)
    teardown = SimRobot.teardown
    monkeypatch.setattr(SimRobot, "teardown", lambda self: (order.append("teardown"), teardown(self)))

    obs = StopAfterMoves(2)
    runner = Runner(graph_from(RECIPE), observers=[obs])
    obs.runner = runner
    summary = runner.run()
    assert summary.outcome == "interrupted"
    assert order == ["halt", "teardown"]  # motion stops before anything is torn down
    (ev,) = [e for e in summary.events if e.code == "halted"]
    assert ev.stage == "robot" and "interrupted (Ctrl-C)" in ev.message

    order.clear()
    summary = Runner(graph_from(RECIPE, ["campaign.n_poses=2"])).run()
    assert summary.outcome == "ok" and order == ["teardown"]
