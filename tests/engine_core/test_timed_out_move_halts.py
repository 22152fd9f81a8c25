"""A move whose caller stops waiting (the docking move times out: alarm ``robot_unavailable``) is
halted: the run's data is complete, but the robot is still serving the move, so the runner halts it
as a stop would, waits for the reply, and only then ends the robot's streams. Before, the robot went
on for the rest of its move, no ``halted`` event was written, and the robot stage died publishing on
an ended port."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from engine.graph import build_graph
from engine.plugin_manager import load_registry
from engine.recipe.model import load_recipe
from engine.run.runner import Observer, Runner

pytestmark = pytest.mark.timeout(120)

DOCK = Path(__file__).resolve().parents[2] / "recipes/eye_in_hand_dock.yaml"


class PoseTimes(Observer):
    """Monotonic times of the robot's ``tcp_pose`` samples and of the run's ``halted`` event."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.pose_at: list[float] = []
        self.halted_at: float | None = None

    def on_publish(self, stage, port, payload, envelope, msg) -> None:
        if stage == "robot" and port == "tcp_pose":
            with self.lock:
                self.pose_at.append(time.monotonic())

    def on_run_event(self, ev) -> None:
        if ev.code == "halted" and self.halted_at is None:
            self.halted_at = time.monotonic()


def test_a_docking_move_that_times_out_is_halted_and_the_robot_stops_publishing():
    overrides = ["clock=wall", "docking.timeout_s=1", "robot.move_j_speed_rad_s=0.1"]
    loaded = load_recipe(str(DOCK), overrides)
    obs = PoseTimes()
    summary = Runner(build_graph(loaded, load_registry(loaded.recipe.plugins)), observers=[obs]).run()

    alarms = [e for e in summary.events if e.level == "alarm"]
    assert [e.code for e in alarms] == ["robot_unavailable"], summary.events
    assert summary.outcome != "ok" and summary.exit_code == 1
    (halted,) = [e for e in summary.events if e.code == "halted"]
    assert halted.stage == "robot" and "'move'" in halted.message
    # no stage died: the robot's last samples were published before its streams ended
    assert not [s.name for s in summary.stages if s.state == "failed"], summary.stages
    assert not [e for e in summary.events if e.level == "error"], [e.message for e in summary.events]
    # the move at 0.1 rad/s had seconds left: the robot came to rest within a fraction of a second
    assert obs.halted_at is not None
    after = [t - obs.halted_at for t in obs.pose_at if t > obs.halted_at]
    assert len(after) <= 2 and all(dt < 0.6 for dt in after), after  # (decelerating; then the pose at rest)
