"""After the run is told to stop (Ctrl-C, a failure, a stop request) no stage sends a new service
request: a data-collection campaign commands no robot move past the stop."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from recipe_helpers import graph_from

from engine.run.runner import Observer, Runner

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


class RunEvents(Observer):
    """Keeps the runner's own events (the stop and its steps)."""

    def __init__(self) -> None:
        self.events: list = []

    def on_run_event(self, ev) -> None:
        self.events.append(ev)

    def codes(self, stage: str | None = None) -> list[str]:
        return [e.code for e in self.events if stage is None or e.stage == stage]


def stop_when(runner: Runner, ready, reason: str = "interrupted (Ctrl-C)") -> threading.Thread:
    """Stops *runner* (as Ctrl-C does) from another thread once ``ready()`` holds (20 s at most)."""

    def watch() -> None:
        deadline = time.monotonic() + 20
        while not ready() and time.monotonic() < deadline:
            time.sleep(0.01)
        runner.stop(reason)

    th = threading.Thread(target=watch, daemon=True)
    th.start()
    return th


BUSY = """
name: busy
plugins: [stage_fixtures]
clock: wall
stages:
  src: {type: t_counter, params: {n: 1}}
  slow: {type: t_busy, params: {busy_s: 30}}
  call: {type: t_caller, inputs: {in: src.out}, uses: {svc: slow.work}, params: {timeout_s: 60}}
"""


def test_a_call_waiting_for_its_reply_returns_at_the_stop_and_a_busy_stage_is_reported_once(monkeypatch):
    from stage_fixtures import BUSY_RELEASE, BUSY_STARTED

    thread_errors: list = []
    monkeypatch.setattr(threading, "excepthook", thread_errors.append)
    events = RunEvents()
    runner = Runner(graph_from(BUSY), run_id="busy-stop", observers=[events])
    # the caller has sent its request and the busy stage is at work on it (not looking at the stop
    # for 30 s); stopping before the work began would leave nothing stuck (seen on a loaded machine)
    stop_when(
        runner,
        lambda: (
            "call" in runner.runtimes
            and runner.runtimes["call"].stats.calls_made == 1
            and BUSY_STARTED["busy-stop"].is_set()
        ),
    )
    try:
        summary = runner.run()
        assert summary.outcome == "interrupted" and summary.exit_code == 130
        # the caller's call was cut short: it ended with the stop, quietly (no error, no traceback)
        assert "stage_stopped" in events.codes("call")
        assert not [e for e in summary.events if e.level == "error" or e.traceback], summary.events
        assert runner.runtimes["call"].stats.state == "stopped"
        # only the stage busy in its computation outlived the grace period: one warning, no traceback
        (stuck,) = [e for e in summary.events if e.code == "stage_stuck"]
        assert stuck.stage == "slow" and stuck.level == "warning" and not stuck.traceback
        assert events.codes("slow") == ["stage_stuck"]
        assert events.codes()[-1] == "stop_done"
        # the run ended a grace period after the stop, not when the 60 s call would have timed out
        # (a generous bound; measured by the run itself)
        assert summary.stop_to_end_s is not None and summary.stop_to_end_s < 5.0
    finally:
        BUSY_RELEASE["busy-stop"].set()  # the busy stage finishes, after its bus has closed...
    th = next(t for t in runner.runtimes["slow"].threads if t.name.endswith("srv.work"))
    th.join(10)
    assert not th.is_alive()
    assert not thread_errors  # ...and its late reply goes nowhere, without an exception


HELPER = """
name: helper
plugins: [stage_fixtures]
clock: wall
stages:
  echo: {type: t_echo}
  calls: {type: t_helper_caller, uses: {svc: echo.echo}}
"""


def test_a_helper_thread_of_a_stage_sends_nothing_after_the_stop():
    from stage_fixtures import HELPER_CALLS

    runner = Runner(graph_from(HELPER), run_id="helper-stop")
    stop_when(runner, lambda: HELPER_CALLS["helper-stop"].get("answered", 0) >= 20)
    summary = runner.run()
    assert summary.outcome == "interrupted"
    seen = HELPER_CALLS["helper-stop"]
    assert seen["ended_by"] == "RunStoppingError"
    # the source the stop ended is said to be stopped, not finished
    assert runner.runtimes["calls"].stats.state == "stopped"
    # every request the echo stage served was answered to the helper (at most one in flight was cut)
    served = runner.runtimes["echo"].stats.requests_served
    assert seen["answered"] <= served <= seen["answered"] + 1
    assert summary.stop_to_end_s is not None and summary.stop_to_end_s < 5.0


class StopMidMove(RunEvents):
    """Stops the run (as Ctrl-C does) while the robot is in the middle of the campaign's 2nd move."""

    def __init__(self) -> None:
        super().__init__()
        self.runner: Runner | None = None
        self.moves_answered = 0
        self.samples_of_move_2 = 0

    def on_service(self, call) -> None:
        if call.stage == "campaign" and call.client == "robot":
            self.moves_answered += 1

    def on_publish(self, stage, port, payload, envelope, msg) -> None:
        if stage == "robot" and port == "joint_state" and self.moves_answered == 1:
            self.samples_of_move_2 += 1
            if self.samples_of_move_2 == 3:  # 3 samples at 25 Hz into a ~2 s move
                assert self.runner is not None
                self.runner.stop("interrupted (Ctrl-C)")


def test_ctrl_c_mid_move_halts_the_robot_on_its_path_and_no_further_move_is_sent(tmp_path):
    from engine.messages import Event, codec
    from engine.recording.reader import load
    from engine.recording.recorder import Recorder

    # real (wall-clock) time: the second move lasts ~2 s (60 deg at 0.5 rad/s) and is cut short
    obs = StopMidMove()
    overrides = [
        "clock=wall",
        "campaign.speed=0.5",
        "campaign.poses_deg=[[0,-90,0,-90,0,0],[60,-90,0,-90,0,0],[0,-60,0,-90,0,0]]",
    ]
    graph = graph_from(RECIPE, overrides)
    recorder = Recorder(tmp_path / "stopped.mcap", graph.recipe.record, graph.loaded, ["builtin"])
    runner = Runner(graph, observers=[obs, recorder])
    obs.runner = runner
    summary = runner.run()
    assert summary.outcome == "interrupted" and summary.exit_code == 130
    ctl = runner.runtimes["robot"].stage.ctl
    # the controller got the two moves sent before the stop and nothing after it
    assert [cid for cid in ctl._results] == ["campaign-1-0", "campaign-1-1"]
    # the move in progress was halted: it decelerated on its path and the robot is at rest, short of its target
    halted = ctl.result("campaign-1-1")
    assert halted.halted and not ctl.is_moving(halted.end_s)
    assert abs(np.degrees(ctl.state(halted.end_s).q[0])) < 59.0
    assert "halted" in obs.codes("robot")
    # the campaign's waiting call was cut short: it ended quietly (no robot_unavailable alarm, no error)
    assert runner.runtimes["campaign"].stats.state == "stopped"
    assert not [e for e in summary.events if e.level in ("error", "alarm")], summary.events
    # every stage ended, none was left behind (and a generous bound on the time, measured by the run)
    assert "stage_stuck" not in obs.codes()
    assert summary.stop_to_end_s is not None and summary.stop_to_end_s < 5.0

    # the shutdown is in the recording: the stop and its reason, the halt, the stages it ended
    rec = load(tmp_path / "stopped.mcap")
    run = [codec.decode_payload(Event, m.payload) for m in rec.messages("/_vgr/run")]
    assert [(e.code, e.stage) for e in run[:2]] == [("stop", ""), ("halted", "robot")]
    assert run[0].details["reason"] == "interrupted (Ctrl-C)" and run[-1].code == "stop_done"
    stopped = {e.stage: e.details["after_s"] for e in run if e.code == "stage_stopped"}
    # the stages whose threads were busy: robot, campaign, and start, whose thread runs the campaign's
    # handler (the campaign was idle when start published); tracker, a source, had ended
    assert set(stopped) == {"robot", "campaign", "start"} and max(stopped.values()) < 5.0
    moved = [codec.decode_payload(Event, m.payload) for m in rec.messages("/robot/events")]
    assert [e.details["command_id"] for e in moved if e.code == "move_halted"] == ["campaign-1-1"]
    ended = [codec.decode_payload(Event, m.payload) for m in rec.messages("/campaign/events")]
    assert [e.code for e in ended][-1:] == ["stopped"]
    # the move commands in the recording: the two sent, the second cut short by the stop, no third
    moves = [r[1] for r in rec.records if r[0] == "svc" and r[1].caller == "campaign" and r[1].client == "robot"]
    assert [m.request_seq for m in moves] == [1, 2] and "run is stopping" in moves[1].error
    meta = rec.metadata["vgr.summary"]
    assert meta["outcome"] == "interrupted" and meta["stop_reason"] == "interrupted (Ctrl-C)"
    assert float(meta["stop_to_end_s"]) < 5.0
