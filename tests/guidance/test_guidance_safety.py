"""Safety of the guidance and docking stages: on doubt, no motion and an alarm.

Each case drives the real ``guidance`` / ``docking`` stages through a scripted context: the robot,
camera and matcher services are Python functions, and every move the robot is asked for is kept.
"Photo" is the move to the photo pose that starts every job; after a refusal nothing else may move.
The same paths through the whole engine (recorded alarms in the MCAP) are in test_guidance_recipes.py.
"""

from __future__ import annotations

import logging
import threading
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from engine.clock import SimClock
from engine.messages import Correction, Event, Message, PointCloud, Request, RobotCommand, RobotReply, freeze
from engine.stage import ServiceTimeoutError, Stage, StageContext, stage_rng
from engine.transforms import T_from_Rt
from plugins.actions.messages import GuidanceResult
from plugins.actions.stages.docking import Docking
from plugins.actions.stages.guidance import Guidance
from plugins.registration.messages import MatchResult

PHOTO = T_from_Rt(np.diag([1.0, -1.0, -1.0]), (0.4, 0.1, 0.4))
X = T_from_Rt(np.eye(3), (0.0, 0.06, 0.03))  # T_tcp_cam


class ScriptedContext(StageContext):
    """Services are functions; publications, events and robot moves are kept."""

    def __init__(self, services: dict[str, Callable[[Message], Message]], name: str = "guidance") -> None:
        self.name, self.run_id, self.seed = name, "unit", 0
        self.rng = stage_rng(0, name)
        self.clock = SimClock()
        self.log = logging.getLogger(f"test.{name}")
        self.services = services
        self.published: dict[str, list[Message]] = defaultdict(list)
        self.events: list[Event] = []
        self._stop = threading.Event()

    def publish(self, port: str, msg: Message) -> None:
        self.published[port].append(freeze(msg))

    def event(self, level: str, code: str, message: str, **details: Any) -> None:
        self.events.append(Event(level=level, code=code, stage=self.name, message=message, details=details))

    def call(self, client: str, request: Message, timeout_s: float = 10.0) -> Message:
        return self.services[client](request)

    def has_client(self, client: str) -> bool:
        return client in self.services

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def sleep(self, seconds: float) -> bool:
        return self.clock.sleep(seconds, self._stop)

    def alarms(self) -> list[str]:
        return [e.code for e in self.events if e.level == "alarm"]


class Robot:
    """Accepts moves (the TCP goes exactly where asked) unless ``refuse`` says otherwise; ids in
    ``handled_before`` are answered as a controller answers a repeated id (the first reply again:
    ok, an old pose, ``duplicate``) without moving."""

    def __init__(
        self, refuse: Callable[[RobotCommand], bool] = lambda cmd: False, handled_before: frozenset[str] = frozenset()
    ) -> None:
        self.moves: list[str] = []
        self.refuse = refuse
        self.handled_before = handled_before

    def __call__(self, cmd: Message) -> RobotReply:
        assert isinstance(cmd, RobotCommand)
        if cmd.command_id in self.handled_before:
            return RobotReply(command_id=cmd.command_id, ok=True, T=np.eye(4), duplicate=True)
        if self.refuse(cmd):
            return RobotReply(command_id=cmd.command_id, ok=False, error="outside the work envelope")
        self.moves.append(cmd.command_id)
        return RobotReply(command_id=cmd.command_id, ok=True, T=cmd.T)


def camera(_: Message) -> PointCloud:
    return PointCloud(points=np.zeros((10, 3), np.float32), frame_id="camera")


def matches(*results: MatchResult) -> Callable[[Message], MatchResult]:
    queue = list(results)
    return lambda _: queue.pop(0)


def ok(t_mm: float = 5.0, r_deg: float = 2.0) -> MatchResult:
    T = T_from_Rt(Rotation.from_euler("z", r_deg, degrees=True).as_matrix(), (t_mm / 1e3, 0.0, 0.0))
    return MatchResult(method="fine", verdict="ok", T_match=T)


def run_guidance(services: dict[str, Callable[[Message], Message]], **params: Any) -> ScriptedContext:
    ctx = ScriptedContext(services)
    stage: Stage = Guidance(
        ctx,
        Guidance.Params(
            mode="eye_in_hand", hand_eye={"matrix": X.tolist()}, photo_pose={"matrix": PHOTO.tolist()}, **params
        ),
    )
    stage.setup()
    stage.on_message("trigger", Request(command="go", seq=1))
    return ctx


def result_of(ctx: ScriptedContext) -> GuidanceResult:
    (res,) = ctx.published["result"]
    assert isinstance(res, GuidanceResult)
    return res


def test_converges_and_moves_once_per_step() -> None:
    robot = Robot()
    ctx = run_guidance({"robot": robot, "camera": camera, "match": matches(ok(), ok(0.02, 0.001))})
    assert result_of(ctx).verdict == "converged"
    assert robot.moves == ["guidance-1-photo", "guidance-1-1"]
    assert ctx.alarms() == []


def test_step_beyond_the_limit_is_not_moved() -> None:
    robot = Robot()
    ctx = run_guidance({"robot": robot, "camera": camera, "match": matches(ok(t_mm=31.0))}, max_step_mm=30.0)
    assert result_of(ctx).verdict == "refused"
    assert robot.moves == ["guidance-1-photo"]
    assert ctx.alarms() == ["correction_limit"]


def test_total_correction_beyond_the_limit_is_not_moved() -> None:
    robot = Robot()
    looks = matches(ok(t_mm=20.0, r_deg=0.0), ok(t_mm=20.0, r_deg=0.0), ok(t_mm=20.0, r_deg=0.0))
    ctx = run_guidance({"robot": robot, "camera": camera, "match": looks}, max_total_mm=30.0)
    assert result_of(ctx).verdict == "refused"
    assert robot.moves == ["guidance-1-photo", "guidance-1-1"]  # the second 20 mm step would make 40 mm
    assert ctx.alarms() == ["correction_limit"]


@pytest.mark.parametrize("verdict", ["failed", "ambiguous"])
def test_unusable_match_is_not_moved(verdict: str) -> None:
    robot = Robot()
    bad = MatchResult(method="global", verdict=verdict, reasons=["two poses explain the view"])
    ctx = run_guidance({"robot": robot, "camera": camera, "match": matches(bad)})
    res = result_of(ctx)
    assert res.verdict == "failed" and res.match_verdicts == [verdict]
    assert robot.moves == ["guidance-1-photo"]
    assert ctx.alarms() == [f"match_{verdict}"]


def test_nan_pose_is_not_moved() -> None:
    robot = Robot()
    T = ok().T_match.copy()
    T[0, 3] = np.nan
    ctx = run_guidance({"robot": robot, "camera": camera, "match": matches(MatchResult(verdict="ok", T_match=T))})
    assert result_of(ctx).verdict == "failed"
    assert robot.moves == ["guidance-1-photo"]
    assert ctx.alarms() == ["nan"]


def test_robot_refusal_stops_the_loop() -> None:
    robot = Robot(refuse=lambda cmd: cmd.command_id.endswith("-1"))
    ctx = run_guidance({"robot": robot, "camera": camera, "match": matches(ok(), ok())})
    assert result_of(ctx).verdict == "refused"
    assert robot.moves == ["guidance-1-photo"]
    assert ctx.alarms() == ["robot_refused"]


def test_a_repeated_command_id_is_not_taken_for_a_move() -> None:
    """The controller answers an id it handled before (a retry, or an earlier run's journal) with the
    old reply and does not move: guidance must not go on from a pose the robot is not at."""
    robot = Robot(handled_before=frozenset({"guidance-1-photo"}))
    ctx = run_guidance({"robot": robot, "camera": camera, "match": matches(ok(), ok())})
    assert result_of(ctx).verdict == "refused" and robot.moves == []
    assert ctx.alarms() == ["duplicate_command"]


@pytest.mark.parametrize("upstream", ["refused", "failed", "not_converged"])
def test_a_guidance_chained_after_one_that_did_not_converge_moves_nothing(upstream: str) -> None:
    """Dual docking: the eye-to-hand guidance is triggered by the eye-in-hand one's ``done``; when
    that one did not converge, the second must not move to its photo pose and correct."""
    robot = Robot()
    ctx = ScriptedContext({"robot": robot, "camera": camera, "match": matches(ok(0.0, 0.0))})  # (within tolerance)
    stage: Stage = Guidance(
        ctx, Guidance.Params(mode="eye_in_hand", hand_eye={"matrix": X.tolist()}, photo_pose={"matrix": PHOTO.tolist()})
    )
    stage.setup()
    done = Request(command="guidance_done", args={"job": 1, "verdict": upstream}, seq=1)
    stage.on_message("trigger", done)
    assert robot.moves == [] and result_of(ctx).verdict == "refused"
    assert ctx.alarms() == ["upstream_not_converged"] and len(ctx.published["done"]) == 1
    stage.on_message("trigger", Request(command="guidance_done", args={"job": 2, "verdict": "converged"}, seq=2))
    assert robot.moves == ["guidance-2-photo"]  # a converged one goes ahead (and converges at its first look)
    assert ctx.published["result"][-1].verdict == "converged"


def test_camera_timeout_is_not_moved() -> None:
    def silent_camera(_: Message) -> PointCloud:
        raise ServiceTimeoutError("camera.capture: no reply within 30 s")

    robot = Robot()
    ctx = run_guidance({"robot": robot, "camera": silent_camera, "match": matches(ok())})
    assert result_of(ctx).verdict == "failed"
    assert robot.moves == ["guidance-1-photo"]
    assert ctx.alarms() == ["capture_failed"]


def docking(robot: Robot, **params: Any) -> tuple[Docking, ScriptedContext]:
    """A set-up docking stage that installs at PHOTO, with *robot* as its robot, and its context."""
    ctx = ScriptedContext({"robot": robot}, name="docking")
    dock = Docking(ctx, Docking.Params(install_pose={"matrix": PHOTO.tolist()}, **params))
    dock.setup()
    return dock, ctx


def test_not_converging_raises_an_alarm_and_does_not_dock() -> None:
    robot = Robot()
    looks = matches(*[ok(1.0, 0.1) for _ in range(4)])
    ctx = run_guidance({"robot": robot, "camera": camera, "match": looks}, max_iterations=3)
    res = result_of(ctx)
    assert res.verdict == "not_converged" and res.moves == 3
    assert ctx.alarms() == ["not_converged"]
    dock_robot = Robot()
    dock, dctx = docking(dock_robot, mode="eye_in_hand")
    dock.on_message("guidance", res)
    (corr,) = dctx.published["correction"]
    assert isinstance(corr, Correction) and corr.verdict == "refused"
    assert dock_robot.moves == [] and dctx.alarms() == ["guidance_not_usable"]


def converged(T_start: np.ndarray, T_end: np.ndarray) -> GuidanceResult:
    return GuidanceResult(mode="eye_in_hand", verdict="converged", T_start=T_start, T_end=T_end, job=1)


def test_docking_refuses_a_correction_beyond_its_limit() -> None:
    robot = Robot()
    dock, ctx = docking(robot, max_correction_mm=25.0)
    far = PHOTO.copy()
    far[0, 3] += 0.026
    dock.on_message("guidance", converged(PHOTO, far))
    (corr,) = ctx.published["correction"]
    assert corr.verdict == "refused" and robot.moves == [] and ctx.alarms() == ["correction_limit"]


def test_docking_refuses_nan_and_robot_refusal_is_an_alarm() -> None:
    bad = PHOTO.copy()
    bad[1, 3] = np.nan
    robot = Robot()
    dock, ctx = docking(robot)
    dock.on_message("guidance", converged(PHOTO, bad))
    assert robot.moves == [] and ctx.alarms() == ["nan"]

    refusing = Robot(refuse=lambda cmd: True)
    dock2, ctx2 = docking(refusing)
    dock2.on_message("guidance", converged(PHOTO, PHOTO))
    (corr,) = ctx2.published["correction"]
    assert corr.verdict == "refused" and ctx2.alarms() == ["robot_refused"]

    repeated = Robot(handled_before=frozenset({"docking-1-approach", "docking-1-dock"}))
    dock3, ctx3 = docking(repeated)
    dock3.on_message("guidance", converged(PHOTO, PHOTO))
    (corr,) = ctx3.published["correction"]
    assert corr.verdict == "refused" and ctx3.alarms() == ["duplicate_command"]
    assert "docked" not in [e.code for e in ctx3.events]


def _calibration_file(tmp_path, verdict: str, name: str = "T_tcp_cam") -> str:
    from plugins.calibration.result import CalibrationResult

    result = CalibrationResult(kind="handeye", verdict=verdict, method="ml", estimate={name: X})
    path = tmp_path / "result.json"
    path.write_text(result.to_json())
    return str(path)


def test_hand_eye_comes_from_a_calibration_result_file(tmp_path) -> None:
    ctx = ScriptedContext({"robot": Robot(), "camera": camera, "match": matches(ok(0.01, 0.001))})
    stage = Guidance(ctx, Guidance.Params(hand_eye_file=_calibration_file(tmp_path, "ok")))
    stage.setup()
    assert np.array_equal(stage.X, X)


@pytest.mark.parametrize(("verdict", "name"), [("failed", "T_tcp_cam"), ("ok", "T_base_cam")])
def test_a_failed_or_wrong_calibration_file_is_refused_at_setup(tmp_path, verdict: str, name: str) -> None:
    ctx = ScriptedContext({})
    stage = Guidance(ctx, Guidance.Params(hand_eye_file=_calibration_file(tmp_path, verdict, name)))
    with pytest.raises(ValueError, match=r"may not drive a robot|no T_tcp_cam"):
        stage.setup()
