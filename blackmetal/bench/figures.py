"""Each figure of ``blackmetal bench``, measured in fresh processes on loopback."""

from __future__ import annotations

import itertools
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING

from blackmetal.runtime.harness import ServiceProcess
from blackmetal.schemas import Keys

from .children import spawn, spawn_blackmetal
from .peers import COMMAND_GAP_S, EXPRESS, RobotProcess, _zenoh_conf, free_port, percentiles
from .synth import square_legs, synth_log

if TYPE_CHECKING:
    import zenoh

KEYS = Keys()

CLK_TCK = os.sysconf("SC_CLK_TCK")


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # utime + stime


# Every figure starts its processes on an ExitStack: each is stopped when the figure ends, however it ends
# (in reverse order: clients, then the gateway, then the robot), from the moment it exists.


def _service(stack: ExitStack, name: str, command: list[str]) -> ServiceProcess:
    child = spawn_blackmetal(name, command)
    stack.callback(child.stop)
    child.wait_ready()
    return child


def latch_args(stack: ExitStack) -> list[str]:
    """A bench's gateway keeps its e-stop latch in a folder of its own, released at first: its robots are the bench's own."""
    folder = stack.enter_context(tempfile.TemporaryDirectory(prefix="blackmetal-bench-state-"))
    return ["--state-dir", folder, "--unsafe-start-released"]


def mini_robot(stack: ExitStack) -> RobotProcess:
    return stack.enter_context(RobotProcess())


def gateway(stack: ExitStack, robot: RobotProcess, zport: int, poll_hz: float, listen: bool = True) -> ServiceProcess:
    zenoh_args = ["--no-multicast-scouting", "-l" if listen else "-e", f"tcp/127.0.0.1:{zport}"]
    return _service(
        stack,
        "gateway",
        ["gateway", "--control-port", str(robot.control_port), "--log-port", str(robot.log_port),
         "--poll-hz", str(poll_hz), "--cmd-timeout", "0", *latch_args(stack), *zenoh_args],
    )  # fmt: skip


def odometry(stack: ExitStack, zport: int, listen: int | None = None) -> ServiceProcess:
    """The odometry, a client of the gateway's endpoint; with ``listen``, a peer that clients can reach directly."""
    zenoh_args = ["-e", f"tcp/127.0.0.1:{zport}"] + (["-l", f"tcp/127.0.0.1:{listen}"] if listen else [])
    return _service(stack, "odometry", ["odometry", *zenoh_args])


def wait_polls(robot: RobotProcess, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while not robot.dump()["polls"]:
        if time.monotonic() > deadline:
            raise TimeoutError(f"the gateway did not poll the robot within {timeout:g} s")
        time.sleep(0.1)


def ros2_adapter(stack: ExitStack, zport: int, listen: int | None = None) -> ServiceProcess:
    """``blackmetal ros2`` (rmw_zenoh flavour), a client of the gateway's endpoint; with ``listen``, a peer ROS nodes reach directly."""
    zenoh_args = ["-e", f"tcp/127.0.0.1:{zport}"] + (["-l", f"tcp/127.0.0.1:{listen}"] if listen else [])
    return _service(stack, "ros2", ["ros2", *zenoh_args])


def cmd_latency(samples: int, poll_hz: float = 50.0, via_ros2: bool = False, ros2_in_line: bool = False) -> dict[str, float]:
    """``cmd_vel`` put -> command bytes at the robot's socket (the kernel's receive stamp, Unix time).

    With ``via_ros2`` the put is a CDR Twist on rmw_zenoh's ``/cmd_vel`` key,
    through ``blackmetal ros2`` (a CDR decode and more Zenoh hops). The
    publisher is a client of the gateway, which forwards the ROS key to the
    adapter (publisher -> gateway -> adapter -> gateway: a router's place in
    the path, two more transits than the direct put); ``ros2_in_line`` makes
    it a client of the adapter instead (publisher -> adapter -> gateway, as a
    ROS node beside the adapter: one more hop than the direct put).
    """
    import zenoh

    with ExitStack() as stack:
        robot = mini_robot(stack)
        zport = free_port()
        gateway(stack, robot, zport, poll_hz)
        adapter_port = free_port() if ros2_in_line else None
        adapter = ros2_adapter(stack, zport, adapter_port) if via_ros2 else None
        session = stack.enter_context(zenoh.open(_zenoh_conf(connect=adapter_port or zport)))
        if adapter is not None:
            from blackmetal.ros2.messages import RosCodec

            codec = RosCodec()
            pub = session.declare_publisher(adapter.wait_ready()["keys"]["cmd_vel"], express=EXPRESS)

            def payload(speed: float) -> bytes:
                return codec.encode_twist(speed, 0.0)
        else:
            pub = session.declare_publisher(KEYS.cmd_vel, express=EXPRESS)
            payload = _json_twist

        wait_polls(robot)
        return command_latencies(pub, robot, samples, payload)


def _json_twist(speed: float) -> bytes:
    return b'{"linear":{"x":%.6f}}' % speed


def command_latencies(
    pub: "zenoh.Publisher", robot: RobotProcess, samples: int, payload: Callable[[float], bytes] = _json_twist
) -> dict[str, float]:
    """Commands put on ``pub`` (30 of warm-up, then ``samples``), each a distinct speed: put -> arrival at the robot's socket."""
    time.sleep(0.3)
    sent: dict[float, float] = {}
    for i in range(samples + 30):
        speed = round(0.0005 * (1 + i), 6) * (1 if i % 2 else -1)
        data = payload(speed)
        start = time.time()
        pub.put(data)
        if i >= 30:  # warm-up
            sent[speed] = start
        time.sleep(random.uniform(*COMMAND_GAP_S))
    time.sleep(0.3)
    arrivals = {float(k): v for k, v in robot.dump()["arrivals"]}
    return percentiles([arrivals[s] - t for s, t in sent.items() if s in arrivals])


def estop_latency(samples: int, poll_hz: float = 50.0) -> dict[str, float]:
    """``{"engaged": true}`` put on estop -> EMG_STOP bytes at the robot's socket (kernel receive stamp)."""
    import zenoh

    with ExitStack() as stack:
        robot = mini_robot(stack)
        zport = free_port()
        gateway(stack, robot, zport, poll_hz)
        session = stack.enter_context(zenoh.open(_zenoh_conf(connect=zport)))
        pub = session.declare_publisher(KEYS.estop, express=EXPRESS)
        release = session.declare_publisher(KEYS.estop_release, express=EXPRESS)
        wait_polls(robot)
        return estop_latencies(pub, release, robot, samples)


#: After a release, before the next engage, where the gateway's loop is busy (a fleet): the gateway keeps only the
#: newest e-stop state, so an engage that finds the release still waiting merges with it and needs no new EMG_STOP.
RELEASE_SETTLE_S = 0.03


def estop_latencies(
    pub: "zenoh.Publisher", release: "zenoh.Publisher", robot: RobotProcess, samples: int, settle: float = 0.0
) -> dict[str, float]:
    """Engage on ``pub`` (then release on ``release``), 10 of warm-up, then ``samples``: put -> EMG_STOP at the robot's socket.

    ``settle``: extra pause after each release (RELEASE_SETTLE_S for a fleet). ``missing``: engages without an
    EMG_STOP before the next engage (merged with a release still waiting, or slower than the pause).
    """
    time.sleep(0.3)
    first = len(robot.dump()["emg_stops"])
    starts = []
    for _ in range(samples + 10):
        time.sleep(random.uniform(*COMMAND_GAP_S))  # paced like cmd_vel's figure
        starts.append(time.time())
        pub.put(b'{"engaged": true}')
        time.sleep(random.uniform(*COMMAND_GAP_S))
        release.put(b'{"engaged": false}')
        time.sleep(settle)
    time.sleep(0.3)
    stops = sorted(robot.dump()["emg_stops"][first:])
    # each engage's EMG_STOP is the first to arrive before the next engage was put; an engage without one merged
    # with a release still waiting (or took longer than the pause): counted, never paired with another's stop
    ends = [*starts[1:], float("inf")]
    latencies, missing = [], 0
    for index, (start, end) in enumerate(zip(starts, ends, strict=True)):
        arrival = next((stop for stop in stops if start <= stop < end), None)
        if index < 10:
            continue  # warm-up
        if arrival is None:
            missing += 1
        else:
            latencies.append(arrival - start)
    return {**percentiles(latencies), "missing": missing}


def estop_under_flood(samples: int, flooders: int = 3, poll_hz: float = 50.0) -> dict[str, float]:
    """The e-stop's latency while ``flooders`` processes flood ``cmd_vel/nav`` at full speed (an attacker, or a runaway planner)."""
    import zenoh

    with ExitStack() as stack:
        robot = mini_robot(stack)
        zport = free_port()
        gateway(stack, robot, zport, poll_hz)
        session = stack.enter_context(zenoh.open(_zenoh_conf(connect=zport)))
        pub = session.declare_publisher(KEYS.estop, express=EXPRESS)
        release = session.declare_publisher(KEYS.estop_release, express=EXPRESS)
        wait_polls(robot)
        seconds = 4.0 + samples * 0.05
        children = [
            spawn("flooder", ["-m", "blackmetal.bench", "flooder", str(zport), KEYS.cmd_vel_of("nav"), str(seconds)])
            for _ in range(flooders)
        ]
        for child in children:
            stack.callback(child.stop, 3)
            child.wait_ready()
        time.sleep(1.0)  # the flood is on: the gateway's nav input has changed over to its ring buffer
        starts = []
        for _ in range(samples):
            time.sleep(random.uniform(0.02, 0.04))
            starts.append(time.time())
            pub.put(b'{"engaged": true}')
            time.sleep(random.uniform(0.02, 0.04))
            release.put(b'{"engaged": false}')
        time.sleep(0.5)
        stops = robot.dump()["emg_stops"]
    latencies = []
    for start in starts:  # the first EMG_STOP at or after each engage
        after = [stop for stop in stops if stop >= start]
        latencies.append(min(after) - start if after else float("inf"))
    return {**percentiles(latencies), "flooders": flooders, "lost": sum(1 for x in latencies if x == float("inf"))}


def ros2_odom_rate(seconds: float, poll_hz: float = 100.0, warmup: float = 1.0) -> dict[str, float]:
    """Poses on ``<prefix>/pose`` and ``/odom`` samples from ``blackmetal ros2`` counted over the same window.

    ``warmup`` is waited before the window, and is also the window of the adapter's CPU share.
    """
    import zenoh

    counts = {"pose": 0, "odom": 0}
    with ExitStack() as stack:
        robot = mini_robot(stack)
        zport = free_port()
        gateway(stack, robot, zport, poll_hz)
        odometry(stack, zport)
        adapter = ros2_adapter(stack, zport)
        session = stack.enter_context(zenoh.open(_zenoh_conf(connect=zport)))
        session.declare_subscriber(KEYS.pose, lambda s: counts.__setitem__("pose", counts["pose"] + 1))
        odom_key = adapter.wait_ready()["keys"]["odom"]
        session.declare_subscriber(odom_key, lambda s: counts.__setitem__("odom", counts["odom"] + 1))
        wait_polls(robot)
        time.sleep(warmup)
        start = dict(counts)
        started = time.monotonic()
        time.sleep(seconds)
        end, elapsed = dict(counts), time.monotonic() - started
        cpu, cpu_started = cpu_seconds(adapter.proc.pid), time.monotonic()
        time.sleep(warmup)
        cpu_pct = 100 * (cpu_seconds(adapter.proc.pid) - cpu) / (time.monotonic() - cpu_started)
    pose_hz = (end["pose"] - start["pose"]) / elapsed
    odom_hz = (end["odom"] - start["odom"]) / elapsed
    return {"pose_hz": pose_hz, "odom_hz": odom_hz, "ratio": odom_hz / pose_hz if pose_hz else float("nan"), "adapter_cpu_pct": cpu_pct}


def pose_latency(seconds: float, poll_hz: float = 50.0) -> dict[str, float]:
    """Speed reply at the gateway (the impulse stamp) -> Pose received by a client: two Zenoh hops."""
    import zenoh

    from blackmetal.schemas import Pose, decode

    latencies: list[float] = []
    with ExitStack() as stack:
        robot = mini_robot(stack)
        zport, oport = free_port(), free_port()
        gateway(stack, robot, zport, poll_hz)
        odometry(stack, zport, listen=oport)  # gateway -> odometry -> this client: two hops, as the baseline
        session = stack.enter_context(zenoh.open(_zenoh_conf(connect=oport)))
        session.declare_subscriber(KEYS.pose, lambda s: latencies.append(time.time() - decode(Pose, s.payload.to_bytes()).stamp))
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
        robot = mini_robot(stack)
        gateway(stack, robot, free_port(), poll_hz)
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


_REPLAY_SNIPPET = """
import sys, time
t0 = time.perf_counter()
from blackmetal.odometry_service.replay import replay_file
t1 = time.perf_counter()
result = replay_file(sys.argv[1])
t2 = time.perf_counter()
print(len(result), t2 - t1)
"""

_MCAP_REPLAY_SNIPPET = """
import sys, time
from blackmetal.tools.replay import load_impulses
from blackmetal.odometry_service.replay import read_log
import mcap.records, mcap.stream_reader, zstandard  # imported before the clock starts, as the JSON-lines figure does
t1 = time.perf_counter()
data, _ = load_impulses(sys.argv[1], None)
result = read_log(data).replay()
t2 = time.perf_counter()
print(len(result), t2 - t1)
"""

_STREAM_SNIPPET = """
import sys, time, msgspec
from blackmetal.odometry_service.integrator import Odometry
from blackmetal.schemas import WheelImpulses, encode
decoder = msgspec.json.Decoder(WheelImpulses)
lines = open(sys.argv[1], "rb").read().splitlines()[: int(sys.argv[2])]
odo = Odometry()
t0 = time.perf_counter()
for line in lines:
    encode(odo.feed(decoder.decode(line)))
t1 = time.perf_counter()
print(len(lines), t1 - t0)
"""


def mcap_replay(jsonl: Path) -> list[tuple[int, float]]:
    """The same log written as an MCAP recording, replayed three times in fresh processes (file reading included)."""
    from blackmetal.recording.writer import McapRecording

    path = jsonl.with_suffix(".mcap")
    recording = McapRecording(path, KEYS)
    for i, line in enumerate(jsonl.read_bytes().splitlines()):
        recording.write(KEYS.impulses, line, 1_795_000_000_000_000_000 + 10_000_000 * i)
        if i % 100 == 99:  # a chunk per second at 100 Hz, as the recorder writes them
            recording.flush()
    recording.close()
    runs = []
    for _ in range(3):
        out = subprocess.run([sys.executable, "-c", _MCAP_REPLAY_SNIPPET, str(path)], capture_output=True, text=True, check=True)
        count, seconds = out.stdout.split()
        runs.append((int(count), float(seconds)))
    return runs


def calibration_speed(samples: int) -> dict[str, float]:
    """The batch odometry on already-parsed columns (samples/s), one fit evaluation (samples/s), and one fit of a 2 m square pair (s)."""
    import numpy as np

    from blackmetal import robot_model as model
    from blackmetal.odometry_service.batch import integrate, run_batch
    from blackmetal.odometry_service.calibration import Constants, Segment, align, fit_trajectory

    legs = square_legs(side=2.0) * max(1, samples // 3900 + 1)
    log = synth_log(legs, seed=1)
    n = min(samples, len(log))
    seq, stamp, left, right = log.seq[:n], log.stamp[:n], log.left[:n].astype(float), log.right[:n].astype(float)
    # the same drive with 1 % dropouts and 0.5 % spikes per wheel: the repairs' share of the time
    faulty = synth_log(legs, dropout=0.01, spike=0.005, seed=1)
    f_left, f_right = faulty.left[:n].astype(float), faulty.right[:n].astype(float)
    timings, faulty_timings = [], []
    for _ in range(5):
        started = time.perf_counter()
        result = run_batch(seq, stamp, left, right)
        timings.append(time.perf_counter() - started)
        started = time.perf_counter()
        run_batch(faulty.seq[:n], faulty.stamp[:n], f_left, f_right)
        faulty_timings.append(time.perf_counter() - started)
    assert result.d_left is not None and result.d_right is not None
    d_left, d_right = result.d_left, result.d_right
    evals = []
    for _ in range(3):
        started = time.perf_counter()
        integrate(d_left * 1.001, d_right * 0.999, 0.51)
        evals.append(time.perf_counter() - started)
    # a 2 m square each way at 100 Hz, as `blackmetal square --both --size 2` records it
    nominal = Constants(model.IMPULSES_PER_METER_LEFT, model.IMPULSES_PER_METER_RIGHT, model.WHEEL_SEPARATION)
    segments = []
    for clockwise in (False, True):
        pair = synth_log(square_legs(side=2.0, clockwise=clockwise), dt_range=(0.0095, 0.0105), seed=2)
        sl, sr = model.Encoders().to_speeds(pair.left.astype(float), pair.right.astype(float))
        dt = np.diff(pair.stamp, prepend=pair.stamp[0])
        x, y, yaw = integrate(sl * dt * 1.015, sr * dt, 0.515)
        segments.append(Segment(sl * dt, sr * dt, *align(x, y, yaw)))
    started = time.perf_counter()
    fit = fit_trajectory(segments, nominal)
    fit_s = time.perf_counter() - started
    return {
        "samples": n,
        "batch_per_s": n / statistics.median(timings),
        "batch_faulty_per_s": n / statistics.median(faulty_timings),
        "evaluation_per_s": n / statistics.median(evals),
        "fit_s": fit_s,
        "fit_steps": sum(len(seg.d_left) for seg in segments),
        "fit_evaluations": fit.evaluations,
    }


def recorder_load(poll_hz: float, seconds: float, warmup: float = 1.0) -> dict[str, float]:
    """``blackmetal record`` of every key while the gateway polls at ``poll_hz`` and the odometry runs: CPU and bytes/s."""
    with ExitStack() as stack:
        robot = mini_robot(stack)
        zport = free_port()
        gateway(stack, robot, zport, poll_hz)
        odometry(stack, zport)
        path = Path(stack.enter_context(tempfile.TemporaryDirectory())) / "bench.mcap"
        recorder = _service(stack, "record", ["record", "-o", str(path), "-e", f"tcp/127.0.0.1:{zport}"])
        wait_polls(robot)
        time.sleep(warmup)
        cpu0, size0, t0 = cpu_seconds(recorder.proc.pid), path.stat().st_size, time.monotonic()
        time.sleep(seconds)
        cpu1, size1, t1 = cpu_seconds(recorder.proc.pid), path.stat().st_size, time.monotonic()
    return {"poll_hz": poll_hz, "cpu_pct": 100 * (cpu1 - cpu0) / (t1 - t0), "bytes_per_s": (size1 - size0) / (t1 - t0)}


def replay_throughput(samples: int, stream_samples: int, mcap: bool = True) -> dict[str, float]:
    """``blackmetal replay`` (file reading included) against the streaming path, per sample, each in a fresh process.

    With ``mcap`` (it needs the record extra), also the same samples replayed from an MCAP recording.
    """
    legs = square_legs(side=2.0) * max(1, samples // 3900 + 1)
    log = synth_log(legs, dropout=0.01, spike=0.005, seed=1)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "impulses.jsonl"
        path.write_bytes(log.jsonl())
        n = min(samples, len(log))
        if n < len(log):
            lines = path.read_bytes().splitlines(keepends=True)[:n]
            path.write_bytes(b"".join(lines))

        def fresh(snippet: str, *args: str) -> tuple[int, float]:
            out = subprocess.run([sys.executable, "-c", snippet, str(path), *args], capture_output=True, text=True, check=True)
            count, seconds = out.stdout.split()
            return int(count), float(seconds)

        replay_runs = [fresh(_REPLAY_SNIPPET) for _ in range(3)]
        stream_count, stream_seconds = fresh(_STREAM_SNIPPET, str(stream_samples))
        mcap_runs = mcap_replay(path) if mcap else []
    rates = [count / seconds for count, seconds in replay_runs]
    stream_rate = stream_count / stream_seconds
    mcap_figures = {}
    if mcap_runs:
        mcap_rate = statistics.median(count / seconds for count, seconds in mcap_runs)
        mcap_figures = {"mcap_replay_per_s": mcap_rate, "mcap_over_jsonl": mcap_rate / statistics.median(rates)}
    return {
        **mcap_figures,
        "samples": replay_runs[0][0],
        "replay_per_s": statistics.median(rates),
        "replay_min_per_s": min(rates),
        "replay_max_per_s": max(rates),
        "stream_per_s": stream_rate,
        "ratio": statistics.median(rates) / stream_rate,
    }


#: A bare Python process with zenoh imported; it says it is ready as a harness child does (without importing ours).
_BARE_SNIPPET = (
    "import os, sys, time, zenoh; os.write(int(os.environ['BLACKMETAL_READY_FD']), b'{\"service\": \"bare-zenoh\"}\\n'); "
    "time.sleep(float(sys.argv[1]))"
)


def memory_and_cpu(seconds: float, poll_hz: float = 100.0, warmup: float = 1.0) -> dict[str, float]:
    """Resident memory of gateway and odometry after ``seconds`` at ``poll_hz``; the gateway's CPU share."""
    bare = spawn("bare-zenoh", ["-c", _BARE_SNIPPET, "30"])
    try:
        bare.wait_ready()
        time.sleep(0.5)
        baseline = rss_mb(bare.proc.pid)
    finally:
        bare.stop(signal.SIGKILL)
    with ExitStack() as stack:
        robot = mini_robot(stack)
        zport = free_port()
        gw = gateway(stack, robot, zport, poll_hz)
        odo = odometry(stack, zport)
        wait_polls(robot)
        time.sleep(warmup)
        start_rss = (rss_mb(gw.proc.pid), rss_mb(odo.proc.pid))
        cpu0, t0 = cpu_seconds(gw.proc.pid), time.monotonic()
        odo_cpu0 = cpu_seconds(odo.proc.pid)
        time.sleep(seconds)
        cpu1, t1 = cpu_seconds(gw.proc.pid), time.monotonic()
        odo_cpu1 = cpu_seconds(odo.proc.pid)
        end_rss = (rss_mb(gw.proc.pid), rss_mb(odo.proc.pid))
    return {
        "bare_zenoh_mb": baseline,
        "gateway_mb": end_rss[0],
        "odometry_mb": end_rss[1],
        "gateway_over_bare_mb": end_rss[0] - baseline,
        "odometry_over_bare_mb": end_rss[1] - baseline,
        "gateway_growth_mb": end_rss[0] - start_rss[0],
        "odometry_growth_mb": end_rss[1] - start_rss[1],
        "gateway_cpu_pct": 100 * (cpu1 - cpu0) / (t1 - t0),
        "odometry_cpu_pct": 100 * (odo_cpu1 - odo_cpu0) / (t1 - t0),
        "seconds": seconds,
    }


def flood(rate_hz: float, seconds: float) -> dict[str, float]:
    """``cmd_vel`` at ``rate_hz`` for ``seconds``: gateway memory, and how soon the last command reaches the robot."""
    import zenoh

    with ExitStack() as stack:
        robot = mini_robot(stack)
        zport = free_port()
        gw = gateway(stack, robot, zport, 50.0)
        session = stack.enter_context(zenoh.open(_zenoh_conf(connect=zport)))
        pub = session.declare_publisher(KEYS.cmd_vel, express=EXPRESS)
        wait_polls(robot)
        time.sleep(0.3)
        rss_before = rss_mb(gw.proc.pid)
        period = 1.0 / rate_hz
        count = int(rate_hz * seconds)
        start = time.monotonic()
        for i in range(count):
            target = start + i * period
            while time.monotonic() < target:
                pass
            pub.put(b'{"linear":{"x":%.6f}}' % (0.1 + 0.3 * (i % 1000) / 1000))
        last_value = round(0.1 + 0.3 * ((count - 1) % 1000) / 1000, 6)
        final = round(-0.123456, 6)
        t_final = time.time()
        pub.put(b'{"linear":{"x":%.6f}}' % final)
        deadline = time.monotonic() + 5
        arrivals: dict[float, float] = {}
        while time.monotonic() < deadline:
            arrivals = {float(k): v for k, v in robot.dump()["arrivals"]}
            if final in arrivals:
                break
            time.sleep(0.02)
        achieved = count / (time.monotonic() - start)
        rss_after = rss_mb(gw.proc.pid)
        commands = robot.dump()["commands"]
    return {
        "asked_hz": rate_hz,
        "sent_hz": achieved,
        "sent": count + 1,
        "commands_at_robot": commands,
        "rss_before_mb": rss_before,
        "rss_after_mb": rss_after,
        "rss_growth_mb": rss_after - rss_before,
        "last_command_latency_ms": (arrivals[final] - t_final) * 1e3 if final in arrivals else float("nan"),
        "last_flood_value_seen": float(last_value in arrivals),
    }


def arbiter_cost(commands: int, rounds: int = 5) -> dict[str, float]:
    """The arbiter's own cost per command (µs), against the gateway core's whole handling of one cmd_vel, alternating.

    Pure and on a fake clock: the arbiter choosing among the five default sources (and with three locks
    configured), and ``GatewayCore.on_cmd_vel`` (decode, arbiter, limits, encoding the robot's
    command) for the same commands from ``teleop``.
    """
    from blackmetal.gateway.arbiter import Arbiter, LockSpec
    from blackmetal.gateway.core import GatewayCore
    from blackmetal.gateway.settings import GatewaySettings
    from blackmetal.schemas import Twist, Vector3

    twist = Twist(linear=Vector3(x=0.2), angular=Vector3(z=0.1))
    plain = Arbiter()
    locked = Arbiter(locks=(LockSpec("pause", 200, None), LockSpec("supervisor", 60, 0.5), LockSpec("dock", 5, None)))
    settings = GatewaySettings()
    settings.check()
    conn = GatewayCore(settings, 0.0, wallclock=time.time)
    conn.link_up("control", 0.0)
    conn.link_up("log", 0.0)
    conn.take_outgoing("control")
    payloads = [f'{{"linear":{{"x":{0.1 + (i % 7) * 0.01}}},"angular":{{"z":0.1}}}}'.encode() for i in range(commands)]

    def per_command(run: Callable[[int], None]) -> float:
        started = time.perf_counter()
        for i in range(commands):
            run(i)
        return 1e6 * (time.perf_counter() - started) / commands

    clock = [1.0]

    def core(i: int) -> None:
        clock[0] += 0.01  # 100 Hz: each command goes on to the robot (no coalescing)
        conn.on_cmd_vel("teleop", payloads[i], clock[0])
        conn.take_outgoing("control")
        conn.take_events()

    timings: dict[str, list[float]] = {"arbiter_us": [], "arbiter_locks_us": [], "core_us": []}

    def offering(arbiter: Arbiter, base: float) -> Callable[[int], None]:
        def offer(i: int) -> None:
            arbiter.offer("teleop", twist, base + i * 0.01)

        return offer

    for r in range(rounds):
        base = r * commands * 0.01
        timings["arbiter_us"].append(per_command(offering(plain, base)))
        timings["arbiter_locks_us"].append(per_command(offering(locked, base)))
        timings["core_us"].append(per_command(core))
    out = {name: statistics.median(values) for name, values in timings.items()}
    out["arbiter_share"] = out["arbiter_us"] / out["core_us"]
    out["arbiter_locks_share"] = out["arbiter_locks_us"] / out["core_us"]
    out["commands"] = commands
    return out
