"""Ctrl-C, SIGTERM or SIGHUP on `vgr run` of a data-collection recipe while the robot moves (the shipped model-gap
campaign on the simulated cell, in real time with slow moves): the robot is halted, no move is
commanded after the interrupt, every stage ends within the grace period, the command exits 130 with
no traceback, and the recording tells the shutdown (README, *Command line*)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from engine.messages import Event, RobotCommand, RobotReply, codec
from engine.recording.reader import load

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(180)]
ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    "signum,named", [(signal.SIGINT, "Ctrl-C"), (signal.SIGTERM, "SIGTERM"), (signal.SIGHUP, "SIGHUP")]
)
def test_a_stop_signal_halts_the_robot_and_vgr_run_exits_130_without_a_traceback(tmp_path, signum, named):
    """SIGTERM (systemd, containers, kill) and SIGHUP stop as Ctrl-C does: before, SIGTERM ended vgr
    with 143 and no halt, SIGHUP killed it at once."""
    record = tmp_path / "campaign.mcap"
    cmd = [sys.executable, "-m", "engine.cli.main", "run", str(ROOT / "recipes" / "model_gap_sim.yaml")]
    cmd += ["-p", "clock=wall", "-p", "campaign.speed=0.5", "--no-progress", "--record", str(record)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    p = subprocess.Popen(cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # the run is under way once its recording exists (600 polls, 60 s at most); then ~1.5 s into the
        # first move of a random pose at 0.5 rad/s (several seconds long)
        for _ in range(600):
            if record.exists() or p.poll() is not None:
                break
            time.sleep(0.1)
        assert record.exists() and p.poll() is None, "the run did not start"
        time.sleep(1.5)
        p.send_signal(signum)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
    assert p.returncode == 130, out + err
    assert "Traceback" not in out + err, out + err
    assert "run interrupted" in out and f"interrupted ({named})" in out

    rec = load(record)
    assert rec.metadata["vgr.summary"]["outcome"] == "interrupted"
    run = [codec.decode_payload(Event, m.payload) for m in rec.messages("/_vgr/run")]
    codes = [(e.code, e.stage) for e in run]
    assert codes[0] == ("stop", "") and run[0].details["reason"] == f"interrupted ({named})"
    assert codes[1] == ("halted", "robot")  # motion stops first
    assert ("stage_stopped", "campaign") in codes and not [c for c in codes if c[0] == "stage_stuck"]
    assert codes[-1] == ("stop_done", "") and run[-1].details["after_s"] < 5.0  # measured by the run
    # no move after the stop: the commands are the campaign's first ones, in order; every one but
    # the last was answered; the move halted (if the interrupt came mid-move) is the last one sent
    moves = [r[1] for r in rec.records if r[0] == "svc" and r[1].caller == "campaign" and r[1].client == "robot"]
    ids = [codec.decode_payload(RobotCommand, m.request).command_id for m in moves]
    assert ids and ids == [f"campaign-1-{i}" for i in range(len(ids))]
    assert all(not m.error and codec.decode_payload(RobotReply, m.reply).ok for m in moves[:-1])
    robot_events = [codec.decode_payload(Event, m.payload) for m in rec.messages("/robot/events")]
    halted = [e.details["command_id"] for e in robot_events if e.code == "move_halted"]
    assert halted in ([], [ids[-1]])
    # the campaign's call cut short by the stop ended it quietly: no robot_unavailable alarm, no error
    campaign = [codec.decode_payload(Event, m.payload) for m in rec.messages("/campaign/events")]
    assert not [e for e in campaign if e.level in ("alarm", "error")], campaign
    assert "alarm" not in out
