"""The runner: ordered delivery, services, failures as events, prompt stop, clean shutdown."""

from __future__ import annotations

import itertools
import threading
import time

import numpy as np
import pytest
from recipe_helpers import graph_from, header, stages
from stage_fixtures import COLLECTED

from engine.run.runner import Runner

pytestmark = pytest.mark.timeout(60)


def run(text: str, **kw) -> tuple[Runner, object]:
    runner = Runner(graph_from(text), **kw)
    return runner, runner.run()


CHAIN = """
name: chain
plugins: [stage_fixtures]
run_id: {rid}
clock: sim
stages:
  src: {{type: t_counter, params: {{n: {n}}}}}
  mid: {{type: t_relay, inputs: {{in: src.out}}, params: {{fail_at: {fail}}}}}
  sink: {{type: t_collector, inputs: {{in: mid.out}}}}
"""


def test_chain_delivers_every_message_in_order():
    runner, s = run(CHAIN.format(rid="chain1", n=200, fail=-1))
    rows = COLLECTED["chain1"]["sink"]
    assert s.ok and s.stop_reason is None
    assert [r["args"]["i"] for r in rows] == list(range(200))
    assert [r["seq"] for r in rows] == list(range(1, 201))
    assert all(r["args"]["path"] == ["mid"] for r in rows)
    by = {st.name: st for st in s.stages}
    assert by["src"].published["out"] == 200 and by["mid"].received["in"] == 200 and by["sink"].received["in"] == 200
    assert all(st.state == "finished" for st in s.stages)
    assert runner.bus.closed


def test_stage_exception_becomes_an_error_event_with_traceback_and_stops_the_run():
    t0 = time.monotonic()
    _, s = run(CHAIN.format(rid="fail1", n=100, fail=5))
    assert time.monotonic() - t0 < 20
    assert not s.ok and "stage 'mid' failed" in s.stop_reason and "planned failure at i=5" in s.stop_reason
    errors = [e for e in s.events if e.level == "error"]
    assert errors and errors[0].stage == "mid" and errors[0].code == "stage_exception"
    assert "RuntimeError: planned failure at i=5" in errors[0].traceback and "on_message" in errors[0].traceback
    by = {st.name: st for st in s.stages}
    assert by["mid"].state == "failed" and by["mid"].errors == 1


def test_on_error_continue_lets_the_healthy_branch_finish():
    text = header("branches", plugins=["stage_fixtures"], run_id="cont1", on_error="continue") + stages("""
      src: {type: t_counter, params: {n: 30}}
      bad: {type: t_relay, inputs: {in: src.out}, params: {fail_at: 3}}
      good: {type: t_relay, inputs: {in: src.out}}
      sink_bad: {type: t_collector, inputs: {in: bad.out}}
      sink_good: {type: t_collector, inputs: {in: good.out}}
    """)
    _, s = run(text)
    assert len(COLLECTED["cont1"]["sink_good"]) == 30
    assert len(COLLECTED["cont1"]["sink_bad"]) == 3
    assert not s.ok and {st.name: st.state for st in s.stages}["bad"] == "failed"


SERVICE = """
name: svc
plugins: [stage_fixtures]
run_id: {rid}
stages:
  src: {{type: t_counter, params: {{n: 5}}}}
  echo: {{type: t_echo, params: {{delay_s: {delay}}}}}
  call: {{type: t_caller, inputs: {{in: src.out}}, uses: {{svc: echo.echo}}, params: {{command: {cmd}, timeout_s: {to}}}}}
  sink: {{type: t_collector, inputs: {{in: call.out}}}}
"""


def test_service_calls_get_replies():
    _, s = run(SERVICE.format(rid="svc1", delay=0, cmd="echo", to=5))
    rows = COLLECTED["svc1"]["sink"]
    assert s.ok and [r["args"]["i"] for r in rows] == list(range(5))
    assert all(r["args"]["served_by"] == "echo" for r in rows)
    assert {st.name: st for st in s.stages}["echo"].requests_served == 5


def test_provider_exception_is_returned_to_the_caller_and_recorded():
    _, s = run(SERVICE.format(rid="svc2", delay=0, cmd="boom", to=5))
    rows = COLLECTED["svc2"]["sink"]
    assert [r["args"]["error"] for r in rows] == ["ServiceError"] * 5
    assert "ValueError: boom requested" in rows[0]["args"]["text"]
    assert any(e.code == "service_exception" and e.stage == "echo" for e in s.events)


def test_service_timeout_is_reported_as_timeout():
    _, _s = run(SERVICE.format(rid="svc3", delay=0.5, cmd="echo", to=0.1))
    rows = COLLECTED["svc3"]["sink"]
    assert rows and all(r["args"]["error"] == "ServiceTimeoutError" for r in rows)


def test_a_request_whose_caller_gave_up_while_it_queued_is_not_served():
    """Two callers of one busy service, 0.2 s timeouts, 0.5 s per request: the first request is
    served (it started in time), the second waits ~0.3 s behind it, its caller gives up, and the
    provider then skips it (a robot must not start a move nobody waits for any more)."""
    text = header("expiry", plugins=["stage_fixtures"], run_id="exp1") + stages("""
      src: {type: t_counter, params: {n: 1}}
      echo: {type: t_echo, params: {delay_s: 0.5}}
      a: {type: t_caller, inputs: {in: src.out}, uses: {svc: echo.echo}, params: {timeout_s: 0.2}}
      b: {type: t_caller, inputs: {in: src.out}, uses: {svc: echo.echo}, params: {timeout_s: 0.2}}
      sa: {type: t_collector, inputs: {in: a.out}}
      sb: {type: t_collector, inputs: {in: b.out}}
      slow: {type: t_counter, params: {n: 2, rate_hz: 1}}  # keeps the run going past the queue's end
      ss: {type: t_collector, inputs: {in: slow.out}}
    """)
    _, s = run(text)
    rows = COLLECTED["exp1"]["sa"] + COLLECTED["exp1"]["sb"]
    assert [r["args"]["error"] for r in rows] == ["ServiceTimeoutError"] * 2
    assert {st.name: st for st in s.stages}["echo"].requests_served == 1
    expired = [e for e in s.events if e.code == "request_expired"]
    assert len(expired) == 1 and expired[0].stage == "echo" and "stopped waiting" in expired[0].message


def test_stop_from_another_thread_ends_an_endless_run_promptly():
    text = header("endless", plugins=["stage_fixtures"], run_id="stop1") + stages("""
      src: {type: t_counter, params: {forever: true, rate_hz: 2000}}
      mid: {type: t_relay, inputs: {in: src.out}}
      sink: {type: t_collector, inputs: {in: mid.out}}
    """)
    runner = Runner(graph_from(text))
    threading.Timer(0.5, runner.stop, args=("test stop",)).start()
    t0 = time.monotonic()
    s = runner.run()
    assert time.monotonic() - t0 < 10
    assert not s.ok and s.stop_reason == "test stop"
    assert len(COLLECTED["stop1"]["sink"]) > 10
    assert runner.bus.closed


def test_merge_keeps_per_port_order():
    text = header("merge", plugins=["stage_fixtures"], run_id="merge1") + stages("""
      a: {type: t_counter, params: {n: 50}}
      b: {type: t_counter, params: {n: 70}}
      m: {type: t_merge, inputs: {a: a.out, b: b.out}}
      sink: {type: t_collector, inputs: {in: m.out}}
    """)
    _, s = run(text)
    rows = COLLECTED["merge1"]["sink"]
    assert s.ok
    assert [r["args"]["i"] for r in rows if r["command"] == "a"] == list(range(50))
    assert [r["args"]["i"] for r in rows if r["command"] == "b"] == list(range(70))


def test_sim_clock_stamps_are_deterministic():
    text = """
    name: clock
    clock: sim
    run_id: clock1
    stages:
      src: {type: synthetic_cloud, params: {n_points: 10, frames: 5, rate_hz: 10}}
      sink: {type: cloud_stats, inputs: {cloud: src.cloud}}
    """
    runner = Runner(graph_from(text))
    runner.run()
    stamps = [r["stamp_ns"] for r in runner.runtimes["sink"].stage.rows]
    assert [b - a for a, b in itertools.pairwise(stamps)] == [100_000_000] * 4


def test_unknown_process_is_refused():
    from engine.run.runner import RunError

    with pytest.raises(RunError, match="no stage in process 'elsewhere'"):
        Runner(graph_from(CHAIN.format(rid="x", n=1, fail=-1)), process="elsewhere")


def test_published_arrays_are_frozen_and_republishing_does_not_mutate_inputs():
    from engine.messages import PointCloud, freeze

    pc = PointCloud(points=np.zeros((3, 3)))
    out = freeze(pc)
    assert out is pc and not pc.points.flags.writeable
    with pytest.raises(ValueError):
        pc.points[0, 0] = 1.0  # a producer writing after publish is caught, not silently shared
    out.seq = 4
    again = freeze(out)
    assert again is not out and again.points is out.points  # passed-on messages are copied, arrays shared


def test_inline_and_threaded_dispatch_give_identical_results():
    rows = {}
    for mode in ("auto", "thread"):
        text = header("d", plugins=["stage_fixtures"], run_id=f"disp_{mode}") + stages(f"""
          a: {{type: t_counter, params: {{n: 300}}}}
          b: {{type: t_counter, params: {{n: 200}}}}
          m: {{type: t_merge, inputs: {{a: a.out, b: b.out}}, dispatch: {mode}}}
          r: {{type: t_relay, inputs: {{in: m.out}}, dispatch: {mode}}}
          sink: {{type: t_collector, inputs: {{in: r.out}}, dispatch: {mode}}}
        """)
        _, s = run(text)
        assert s.ok
        got = COLLECTED[f"disp_{mode}"]["sink"]
        rows[mode] = sorted((r["command"], r["args"]["i"]) for r in got)
        for port, n in (("a", 300), ("b", 200)):
            assert [r["args"]["i"] for r in got if r["command"] == port] == list(range(n))
    assert rows["auto"] == rows["thread"]


def test_overdue_is_measured_from_arrival_and_ignores_what_it_cannot_read():
    import time as _time

    from engine.transport.bus import TIMEOUT_PARAM, overdue_ms

    class Query:
        def __init__(self, params: dict[str, str]) -> None:
            self.parameters = params

    now = _time.monotonic_ns()
    assert overdue_ms(Query({TIMEOUT_PARAM: "100"}), now) is None  # just arrived, 100 ms to go
    late = overdue_ms(Query({TIMEOUT_PARAM: "100"}), now - 300_000_000)  # arrived 300 ms ago
    assert late is not None and 190 < late < 260
    for params in ({}, {TIMEOUT_PARAM: "soon"}):  # a foreign querier that says nothing usable: served
        assert overdue_ms(Query(params), now - 10**12) is None


def test_cloud_stats_says_what_the_clouds_were_at_the_end_of_the_run():
    from plugins.util.stages.clouds import stats_text

    rows = [
        {"n_finite": 30545, "centroid_mm": [1.0, 2.0, 3.0], "extent_mm": [90.0, 60.0, 20.0], "frame_id": "camera"},
        {"n_finite": 30612, "centroid_mm": [-490.04, 80.0, 5.0], "extent_mm": [90.0, 60.0, 20.5], "frame_id": "base"},
    ]
    assert stats_text(rows) == (
        "2 clouds of 30,545-30,612 valid points; the last in base: centroid (-490.0, 80.0, 5.0) mm, "
        "extent 90.0 x 60.0 x 20.5 mm"
    )
    assert stats_text([]) == "no clouds received"
