"""The telemetry figures: what the services publish and what it costs them (docs/performance.md)."""

from __future__ import annotations

import collections
import itertools
import signal
import statistics
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

from . import peers
from .children import spawn
from .peers import free_port, percentiles
from .rig import KEYS, client_service, cpu_seconds, cpu_window, robot_and_gateway, rss_mb, service, session, wait_polls
from .runner import Figure, Plan, Result, Row, at_most, latency_rows, met, noisy, rounds, spreads


def ros2_odom_rate(seconds: float, warmup: float = 1.0) -> dict[str, float]:
    """Poses and ``blackmetal ros2``'s ``/odom`` samples at 100 Hz polling counted over one window; the adapter's CPU over ``warmup``."""
    counts: collections.Counter[str] = collections.Counter()
    with ExitStack() as stack:
        robot, zport, _ = robot_and_gateway(stack, 100.0)
        client_service(stack, "odometry", zport)
        adapter = client_service(stack, "ros2", zport)
        client = session(stack, zport)
        client.declare_subscriber(KEYS.pose, lambda s: counts.update(("pose",)))
        client.declare_subscriber(adapter.wait_ready()["keys"]["odom"], lambda s: counts.update(("odom",)))
        wait_polls(robot)
        time.sleep(warmup)
        start, started = counts.copy(), time.monotonic()
        time.sleep(seconds)
        end, elapsed = counts.copy(), time.monotonic() - started
        cpu_pct = 100 * cpu_window({"adapter": adapter.proc.pid}, warmup)["adapter"]
    pose_hz, odom_hz = ((end[key] - start[key]) / elapsed for key in ("pose", "odom"))
    return {"pose_hz": pose_hz, "odom_hz": odom_hz, "ratio": odom_hz / pose_hz if pose_hz else float("nan"), "adapter_cpu_pct": cpu_pct}


def pose_latency(seconds: float) -> dict[str, float]:
    """Speed reply at the gateway (the impulse stamp) -> Pose received by a client: two Zenoh hops."""
    from blackmetal.schemas import Pose, decode

    latencies: list[float] = []
    with ExitStack() as stack:
        _, zport, _ = robot_and_gateway(stack)
        oport = free_port()
        client_service(stack, "odometry", zport, listen=oport)  # gateway -> odometry -> this client: two hops, as the baseline
        client = session(stack, oport)
        client.declare_subscriber(KEYS.pose, lambda s: latencies.append(time.time() - decode(Pose, s.payload.to_bytes()).stamp))
        deadline = time.monotonic() + 20
        while len(latencies) < 20 and time.monotonic() < deadline:
            time.sleep(0.05)
        latencies.clear()  # warm-up
        time.sleep(seconds)
        samples = list(latencies)
    if not samples:
        raise TimeoutError(f"no Pose reached the client in {seconds:g} s")
    return percentiles(samples)


def poll_rate(poll_hz: float, seconds: float, warmup: float = 0.5) -> dict[str, float]:
    """Sustained poll rate and worst gap, as the robot sees them."""
    with ExitStack() as stack:
        robot, _, _ = robot_and_gateway(stack, poll_hz)
        wait_polls(robot)
        time.sleep(warmup)
        start = len(robot.dump()["polls"])
        time.sleep(seconds)
        window = robot.dump()["polls"][start:]
    if len(window) < 3:
        raise TimeoutError(f"the gateway polled the robot {len(window)} times in {seconds:g} s at {poll_hz:g} Hz")
    gaps = [b - a for a, b in itertools.pairwise(window)]
    rate = (len(window) - 1) / (window[-1] - window[0])
    return {
        "asked_hz": poll_hz,
        "rate_hz": rate,
        "ratio": rate / poll_hz,
        "worst_gap_ms": max(gaps) * 1e3,
        "worst_gap_periods": max(gaps) * poll_hz,
        "median_gap_ms": statistics.median(gaps) * 1e3,
    }


def recorder_load(poll_hz: float, seconds: float, warmup: float = 1.0) -> dict[str, float]:
    """``blackmetal record`` of every key while the gateway polls at ``poll_hz`` and the odometry runs: CPU and bytes/s."""
    with ExitStack() as stack:
        robot, zport, _ = robot_and_gateway(stack, poll_hz)
        client_service(stack, "odometry", zport)
        path = Path(stack.enter_context(tempfile.TemporaryDirectory())) / "bench.mcap"
        recorder = service(stack, "record", ["record", "-o", str(path), "-e", f"tcp/127.0.0.1:{zport}"])
        wait_polls(robot)
        time.sleep(warmup)
        cpu0, size0, t0 = cpu_seconds(recorder.proc.pid), path.stat().st_size, time.monotonic()
        time.sleep(seconds)
        cpu1, size1, t1 = cpu_seconds(recorder.proc.pid), path.stat().st_size, time.monotonic()
    return {"poll_hz": poll_hz, "cpu_pct": 100 * (cpu1 - cpu0) / (t1 - t0), "bytes_per_s": (size1 - size0) / (t1 - t0)}


#: A bare Python process with zenoh imported; it says it is ready as a harness child does (without importing ours).
_BARE_SNIPPET = (
    "import os, sys, time, zenoh; os.write(int(os.environ['BLACKMETAL_READY_FD']), b'{\"service\": \"bare-zenoh\"}\\n'); "
    "time.sleep(float(sys.argv[1]))"
)


def memory_and_cpu(seconds: float, warmup: float = 1.0) -> dict[str, float]:
    """Resident memory of gateway and odometry after ``seconds`` at 100 Hz polling; the gateway's CPU share."""
    bare = spawn("bare-zenoh", ["-c", _BARE_SNIPPET, "30"])
    try:
        bare.wait_ready()
        time.sleep(0.5)
        baseline = rss_mb(bare.proc.pid)
    finally:
        bare.stop(signal.SIGKILL)
    with ExitStack() as stack:
        robot, zport, gw = robot_and_gateway(stack, 100.0)
        odo = client_service(stack, "odometry", zport)
        wait_polls(robot)
        time.sleep(warmup)
        start_rss = (rss_mb(gw.proc.pid), rss_mb(odo.proc.pid))
        cpu = cpu_window({"gateway": gw.proc.pid, "odometry": odo.proc.pid}, seconds)
        end_rss = (rss_mb(gw.proc.pid), rss_mb(odo.proc.pid))
    return {
        "bare_zenoh_mb": baseline,
        "gateway_mb": end_rss[0],
        "odometry_mb": end_rss[1],
        "gateway_over_bare_mb": end_rss[0] - baseline,
        "odometry_over_bare_mb": end_rss[1] - baseline,
        "gateway_growth_mb": end_rss[0] - start_rss[0],
        "odometry_growth_mb": end_rss[1] - start_rss[1],
        "gateway_cpu_pct": 100 * cpu["gateway"],
        "odometry_cpu_pct": 100 * cpu["odometry"],
        "seconds": seconds,
    }


def _pose(plan: Plan, out: Result) -> Result:
    def two_hops() -> dict[str, float]:  # the baseline paced like the polls (50 Hz): the same idle time between samples
        hop = peers.zenoh_hop(plan.samples // 2, gap=(0.019, 0.021))
        return {"p50_ms": hop["rtt_p50_ms"], "p99_ms": hop["rtt_p99_ms"]}

    measured = rounds(plan, two=two_hops, pose=lambda: pose_latency(plan.pick(0.5, 4.0)))
    two, pose = measured["two"], measured["pose"]
    ratio = statistics.median(pose["p50"]) / statistics.median(two["p50"])
    return {
        "two_hops_ms": spreads(two),
        "impulse_to_pose_ms": {**spreads(pose), "p50_over_two_hops": ratio, "noisy": noisy(pose["p50"]) or noisy(two["p50"])},
    }


def _pose_rows(f: Result) -> list[Row]:
    pose = f["impulse_to_pose_ms"]
    return latency_rows(
        "impulse -> Pose at client {p}", pose, "2 Zenoh hops", f["two_hops_ms"], at_most(pose["p50_over_two_hops"], 1.5, pose["noisy"])
    )


def _ros2_odom_rows(f: Result) -> list[Row]:
    o = f["ros2_odom"]
    return [
        ("/odom rate at 100 Hz polling", f"{o['odom_hz']:.1f} Hz; adapter CPU {o['adapter_cpu_pct']:.1f}%", f"pose {o['pose_hz']:.1f} Hz",
         f"{100 * o['ratio']:.1f}% (= pose rate{met(abs(o['ratio'] - 1) <= 0.01)})")
    ]  # fmt: skip


def _poll_rows(f: Result) -> list[Row]:
    return [
        (f"poll at {hz} Hz", f"{p['rate_hz']:.1f} Hz, worst gap {p['worst_gap_ms']:.1f} ms", f"asked {hz} Hz",
         f"{100 * p['ratio']:.1f}% (>= 98%), gap {p['worst_gap_periods']:.2f} periods (<= 3){met(p['ratio'] >= 0.98 and p['worst_gap_periods'] <= 3)}")
        for hz, p in f["poll"].items()
    ]  # fmt: skip


def _recorder_rows(f: Result) -> list[Row]:
    return [
        (f"recorder at {hz} Hz polling", f"CPU {rec['cpu_pct']:.1f}% of a core, {rec['bytes_per_s'] / 1e3:.1f} kB/s", "-", "report")
        for hz, rec in f["recorder"].items()
    ]


def _memory_rows(f: Result) -> list[Row]:
    m = f["memory"]
    return [
        (f"RSS after {m['seconds']:.0f} s at 100 Hz", f"gateway {m['gateway_mb']:.1f} MB, odometry {m['odometry_mb']:.1f} MB",
         f"bare zenoh {m['bare_zenoh_mb']:.1f} MB", f"+{m['gateway_over_bare_mb']:.1f} / +{m['odometry_over_bare_mb']:.1f} MB (<= +40 MB{met(max(m['gateway_over_bare_mb'], m['odometry_over_bare_mb']) <= 40)})"),
        ("CPU at 100 Hz", f"gateway {m['gateway_cpu_pct']:.1f}%, odometry {m['odometry_cpu_pct']:.1f}% of a core", "-", "report"),
    ]  # fmt: skip


ROS2_ODOM = Figure("ros2_odom", "ROS 2 /odom rate", "ROS 2 /odom rate at 100 Hz polling, against the pose rate ...", ("ros2_odom",),
                   lambda plan, out: {"ros2_odom": ros2_odom_rate(plan.pick(0.5, 10.0), **plan.warmups)}, _ros2_odom_rows, extra="ros2")  # fmt: skip
POSE = Figure("pose", "impulse -> Pose latency", "latency: impulse reply -> Pose at a client, against two Zenoh hops ...",
              ("two_hops_ms", "impulse_to_pose_ms"), _pose, _pose_rows)  # fmt: skip
POLL = Figure("poll", "poll rate", "poll rate at 100 and 200 Hz ...", ("poll",),
              lambda plan, out: {"poll": {str(int(hz)): poll_rate(hz, plan.pick(0.5, 5.0), **plan.warmups) for hz in (100.0, 200.0)}},
              _poll_rows)  # fmt: skip
RECORDER = Figure("recorder", "recorder load", "recorder CPU and bytes/s at 100 and 200 Hz ...", ("recorder",),
                  lambda plan, out: {"recorder": {str(int(hz)): recorder_load(hz, plan.pick(0.5, 10.0), **plan.warmups) for hz in (100.0, 200.0)}},
                  _recorder_rows, extra="record")  # fmt: skip
MEMORY = Figure("memory", "memory and CPU", "memory and CPU at 100 Hz ...", ("memory",),
                lambda plan, out: {"memory": memory_and_cpu(plan.pick(1.0, 60.0), **plan.warmups)}, _memory_rows)  # fmt: skip
