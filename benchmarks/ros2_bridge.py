"""A ROS 2 camera's 1.2 MB PointCloud2 into a vgr stage, against a plain rclpy subscriber, same run.

The publisher is an rclpy node in this process (100 000 points, xyz float32, 12 bytes a point:
1.2 MB), stamping each header with ``time.time_ns()`` just before the publish. Two consumers, each
in a process of its own, both subscribed at once (each cloud meets the same transport for both:
on this host a trial's latency swings between ~3 and ~15 ms for either, trial to trial), started
in alternating order:

``rclpy``  a plain rclpy node: a subscription on a single-threaded executor whose callback takes
           the message rclpy deserialised and makes the numpy array of its points;
``vgr``    ``vgr run`` of a recipe: ``ros2_subscribe`` (plugins/ros2/subscriber_stage.py: raw bytes
           off the executor, converted on the stage's thread by plugins/ros2/convert.py) publishing
           the PointCloud to ``bench_cloud_sink`` (benchmarks/bench_ros2_stages.py) over vgr's bus.

Latency is taken at the entry of the consumer's handler: the clouds at 30 Hz, reliable QoS (depth
10), ``--count`` of them; "delivered" is received / sent. The best-effort row is the same at
sensor-data QoS (what camera drivers publish with): over Fast DDS on this host a plain rclpy
subscriber gets only a few of 60 such 1.2 MB clouds (every fragment of a sample must arrive; with
``FASTDDS_BUILTIN_TRANSPORTS=LARGE_DATA`` too), so it is reported, not targeted. Throughput: the
same clouds as fast as the publisher goes, reliable QoS (keep last 10: a slow reader loses the
oldest), clouds received per second from the first measured send to the last arrival. Targets (issue: vgr in a ROS 2 cell): vgr's p50 latency at most 1.2x
rclpy's, nothing dropped at 30 Hz. Writes benchmarks/results/ros2_bridge.json.

    python benchmarks/ros2_bridge.py [--trials 5] [--count 300] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from bench_results import machine, write_result  # noqa: E402

N_POINTS = 100_000
BEST_EFFORT_COUNT = 60  # clouds of the best-effort row (Fast DDS drops most 1.2 MB best-effort samples)
WARMUP = 10
READY_S = 60.0
RECIPE = """
name: ros2_bridge_bench
plugins: [bench_ros2_stages]
stages:
  ros:
    type: ros2_subscribe
    params:
      ros: {{domain_id: {domain}, discovery: localhost}}
      topics: {{cloud: {{topic: /bench/points, qos: {qos}}}}}
      max_messages: {total}
      duration_s: {duration}
  sink: {{type: bench_cloud_sink, inputs: {{in: ros.cloud}}, params: {{output: "{out}"}}}}
"""


def _env() -> dict[str, str]:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    return env


def _qos(name: str) -> Any:
    from rclpy.qos import QoSProfile, qos_profile_sensor_data

    return qos_profile_sensor_data if name == "sensor_data" else QoSProfile(depth=10)


# --------------------------------------------------------------------------- the plain rclpy consumer
def rclpy_consumer(domain: int, qos: str, total: int, duration_s: float, out: str) -> None:
    """A plain rclpy subscriber (child process): latency at callback entry, JSON to *out*."""
    import rclpy
    from sensor_msgs.msg import PointCloud2

    rclpy.init(domain_id=domain)
    node = rclpy.create_node("bench_rclpy_consumer")
    lat: list[int] = []
    arrivals: list[int] = []

    def on_cloud(msg: PointCloud2) -> None:
        now = time.time_ns()
        lat.append(now - (msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec))
        arrivals.append(now)
        np.frombuffer(msg.data, dtype=np.float32).reshape(-1, 3)  # what a node then works on

    node.create_subscription(PointCloud2, "/bench/points", on_cloud, _qos(qos))
    end = time.monotonic() + duration_s
    while len(lat) < total and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.1)
    Path(out).write_text(json.dumps({"lat_ns": lat, "arrivals_ns": arrivals}))
    node.destroy_node()
    rclpy.shutdown()


# --------------------------------------------------------------------------- the trial
class Publisher:
    """The camera driver: an rclpy node of its own context in this process."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from rclpy.signals import SignalHandlerOptions
        from sensor_msgs.msg import PointCloud2, PointField

        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("bench_camera", context=self.context)
        msg = PointCloud2()
        msg.header.frame_id = "camera"
        msg.height, msg.width = 1, N_POINTS
        msg.fields = [
            PointField(name=c, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, c in enumerate("xyz")
        ]
        msg.is_bigendian, msg.point_step, msg.row_step, msg.is_dense = False, 12, 12 * N_POINTS, True
        msg.data = np.random.default_rng(0).uniform(-1, 1, (N_POINTS, 3)).astype(np.float32).tobytes()
        self.msg = msg
        self.refused = 0  # samples Fast DDS refused to publish (an RCLError), in all trials

    def send(self, qos: str, count: int, interval_s: float, subscribers: int = 1) -> tuple[int, int]:
        """Wait for the consumer's subscription, then publish WARMUP + *count* clouds; how many were
        sent and when the first measured one went (``time.time_ns()``)."""
        pub = self.node.create_publisher(type(self.msg), "/bench/points", _qos(qos))
        deadline = time.monotonic() + READY_S
        while pub.get_subscription_count() < subscribers:
            if time.monotonic() > deadline:
                raise RuntimeError("no consumer subscribed to /bench/points")
            time.sleep(0.05)
        time.sleep(0.5)  # discovery settles both ways
        slot, first_ns, sent = time.perf_counter(), 0, 0
        for i in range(WARMUP + count):
            if interval_s:
                slot += interval_s
                while (d := slot - time.perf_counter()) > 0:
                    time.sleep(d)
            now = time.time_ns()
            first_ns = now if i == WARMUP else first_ns
            self.msg.header.stamp.sec, self.msg.header.stamp.nanosec = divmod(now, 10**9)
            try:
                pub.publish(self.msg)
                sent += 1
            except Exception:  # Fast DDS refuses a sample now and then when flat out: not sent, not counted
                self.refused += 1
        time.sleep(1.0)  # the last ones arrive
        self.node.destroy_publisher(pub)
        return sent, first_ns

    def close(self) -> None:
        import rclpy

        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def consumer_process(
    kind: str, domain: int, qos: str, total: int, duration: float, tmp: Path
) -> tuple[subprocess.Popen, Path]:
    out = tmp / f"{kind}.json"
    if kind == "rclpy":
        args = [sys.executable, __file__, "--consumer", str(domain), qos, str(total), str(duration), str(out)]
    else:
        text = RECIPE.format(domain=domain, qos=qos, total=total, duration=duration, out=out)
        recipe = tmp / "bench.yaml"
        recipe.write_text(text)
        (tmp / "bench_ros2_stages.py").write_text((HERE / "bench_ros2_stages.py").read_text())
        args = [sys.executable, "-m", "engine.cli.main", "run", str(recipe), "--no-progress", "--runs-dir", str(tmp)]
    proc = subprocess.Popen(args, env=_env(), cwd=tmp, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    return proc, out


def _stats(res: dict[str, list[int]], sent: int, first_ns: int) -> dict[str, float]:
    """Latency percentiles, delivered share and receive rate of one consumer's figures."""
    measured = [i for i, t in enumerate(res["arrivals_ns"]) if t - res["lat_ns"][i] >= first_ns]
    lat = np.asarray([res["lat_ns"][i] for i in measured], dtype=float) / 1e3
    last = res["arrivals_ns"][measured[-1]] if measured else first_ns
    rate = len(measured) / ((last - first_ns) / 1e9) if last > first_ns else 0.0  # from the first measured send
    return {
        "delivered": len(res["lat_ns"]) / sent,
        "p50_us": float(np.median(lat)) if len(lat) else float("nan"),
        "p90_us": float(np.percentile(lat, 90)) if len(lat) else float("nan"),
        "msg_per_s": rate,
        "n": len(lat),
    }


def trial(pub: Publisher, order: tuple[str, ...], domain: int, qos: str, count: int, interval_s: float) -> dict:
    """Both consumers subscribed at once (started in *order*), the same clouds to both: each message
    meets the same transport for both, which on this host varies from trial to trial."""
    with tempfile.TemporaryDirectory() as folder:
        duration = 30.0 + (WARMUP + count) * max(interval_s, 0.02)  # a consumer that misses some still ends
        procs = {}
        for kind in order:
            (Path(folder) / kind).mkdir()
            procs[kind] = consumer_process(kind, domain, qos, WARMUP + count, duration, Path(folder) / kind)
        try:
            sent, first_ns = pub.send(qos, count, interval_s, subscribers=len(order))
            errors = {kind: proc.communicate(timeout=180)[1] for kind, (proc, _) in procs.items()}
        finally:
            for proc, _ in procs.values():
                if proc.poll() is None:
                    proc.kill()
        result = {}
        for kind, (proc, out) in procs.items():
            if not out.exists():
                raise RuntimeError(f"{kind} wrote no result (rc {proc.returncode}): {errors[kind].decode()[-2000:]}")
            result[kind] = _stats(json.loads(out.read_text()), sent, first_ns)
    return result


def median_of(rows: list[dict[str, float]]) -> dict[str, float]:
    return {k: float(np.nanmedian([r[k] for r in rows])) for k in rows[0]}  # (a trial may have no figure)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--count", type=int, default=300, help="clouds per trial (after the warm-up)")
    ap.add_argument("--quick", action="store_true", help="1 trial of 60 clouds (never quote it)")
    ap.add_argument("--consumer", nargs=5, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.consumer:
        d, q, t, dur, out = a.consumer
        rclpy_consumer(int(d), q, int(t), float(dur), out)
        return
    trials, count = (1, 60) if a.quick else (a.trials, a.count)
    domain = 150 + os.getpid() % 50
    pub = Publisher(domain)
    rows: dict[str, dict[str, list[dict[str, float]]]] = {"latency_30hz": {}, "best_effort_30hz": {}, "throughput": {}}
    try:
        for i in range(trials):
            order = ("rclpy", "vgr") if i % 2 == 0 else ("vgr", "rclpy")  # which one starts first, alternating
            modes = {
                "latency_30hz": trial(pub, order, domain, "reliable", count, 1 / 30),
                "best_effort_30hz": trial(pub, order, domain, "sensor_data", BEST_EFFORT_COUNT, 1 / 30),
                "throughput": trial(pub, order, domain, "reliable", count, 0.0),
            }
            for mode, by_kind in modes.items():
                for kind, row in by_kind.items():
                    rows[mode].setdefault(kind, []).append(row)
            for kind in order:
                lat, best, thr = (modes[m][kind] for m in modes)
                print(f"trial {i} {kind}: 30 Hz p50 {lat['p50_us']:.0f} us delivered {lat['delivered']:.3f}; "
                      f"best effort delivered {best['delivered']:.3f}; "
                      f"flat out {thr['msg_per_s']:.1f} msg/s delivered {thr['delivered']:.3f}", flush=True)  # fmt: skip
    finally:
        pub.close()
    summary = {mode: {k: median_of(v) for k, v in by.items()} for mode, by in rows.items()}
    ratio = summary["latency_30hz"]["vgr"]["p50_us"] / summary["latency_30hz"]["rclpy"]["p50_us"]
    targets = {
        "p50_latency_ratio": {"value": ratio, "target": 1.2, "pass": ratio <= 1.2},
        "delivered_30hz": {
            "value": summary["latency_30hz"]["vgr"]["delivered"],
            "target": 1.0,
            "pass": min(r["delivered"] for r in rows["latency_30hz"]["vgr"]) >= 1.0,
        },
    }
    result = {
        "benchmark": "ros2_bridge",
        "quick": a.quick,
        "machine": machine(),
        "cloud_bytes": N_POINTS * 12,
        "trials": trials,
        "publish_refused": pub.refused,
        "count": count,
        "summary": summary,
        "targets": targets,
        "runs": rows,
    }
    name = "ros2_bridge_quick.json" if a.quick else "ros2_bridge.json"
    write_result(HERE / "results" / name, result)
    print(json.dumps({"summary": summary, "targets": targets}, indent=2))


if __name__ == "__main__":
    main()
