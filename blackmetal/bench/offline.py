"""The offline figures: replay, calibration and the arbiter's cost, on synthetic logs and a fake clock, with no robot."""

from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from .rig import KEYS
from .runner import Figure, Plan, Result, Row, met, missing_extra
from .synth import square_legs, synth_log

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


def _fresh(snippet: str, *args: str) -> tuple[int, float]:
    """One of the snippets above in a fresh process: how many samples, in how many seconds."""
    out = subprocess.run([sys.executable, "-c", snippet, *args], capture_output=True, text=True, check=True)
    count, seconds = out.stdout.split()
    return int(count), float(seconds)


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


def replay_throughput(samples: int, stream_samples: int, mcap: bool = True) -> dict[str, float]:
    """``blackmetal replay`` (file reading included) against the streaming path, each in a fresh process; MCAP too with ``mcap``."""
    legs = square_legs(side=2.0) * max(1, samples // 3900 + 1)
    log = synth_log(legs, dropout=0.01, spike=0.005, seed=1)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "impulses.jsonl"
        path.write_bytes(b"".join(log.jsonl().splitlines(keepends=True)[:samples]))
        replay_runs = [_fresh(_REPLAY_SNIPPET, str(path)) for _ in range(3)]
        stream_count, stream_seconds = _fresh(_STREAM_SNIPPET, str(path), str(stream_samples))
        mcap_runs = []
        if mcap:  # the same log as an MCAP recording, replayed three times too
            from blackmetal.recording.writer import McapRecording

            recording = McapRecording(path.with_suffix(".mcap"), KEYS)
            for i, line in enumerate(path.read_bytes().splitlines()):
                recording.write(KEYS.impulses, line, 1_795_000_000_000_000_000 + 10_000_000 * i)
                if i % 100 == 99:  # a chunk per second at 100 Hz, as the recorder writes them
                    recording.flush()
            recording.close()
            mcap_runs = [_fresh(_MCAP_REPLAY_SNIPPET, str(recording.path)) for _ in range(3)]
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


def arbiter_cost(commands: int, rounds: int = 5) -> dict[str, float]:
    """The arbiter's own cost per command (µs; five sources, then three locks too) against ``GatewayCore.on_cmd_vel``'s
    whole handling of the same teleop commands, alternating, on a fake clock."""
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

    def per_command(run: Callable[[int], object]) -> float:
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
    for r in range(rounds):
        base = r * commands * 0.01
        for name, arbiter in (("arbiter_us", plain), ("arbiter_locks_us", locked)):
            timings[name].append(per_command(lambda i: arbiter.offer("teleop", twist, base + i * 0.01)))  # noqa: B023 (run at once)
        timings["core_us"].append(per_command(core))
    out = {name: statistics.median(values) for name, values in timings.items()}
    out["arbiter_share"] = out["arbiter_us"] / out["core_us"]
    out["arbiter_locks_share"] = out["arbiter_locks_us"] / out["core_us"]
    out["commands"] = commands
    return out


def _replay(plan: Plan, out: Result) -> Result:
    without_mcap = missing_extra("record")
    if without_mcap is not None:
        plan.progress(f"replay from MCAP: skipped, {without_mcap}")
        out["skipped"]["replay_mcap"] = without_mcap
    replay = replay_throughput(plan.pick(50_000, 1_000_000), plan.pick(5_000, 100_000), mcap=without_mcap is None)
    return {"replay": replay if without_mcap is None else {**replay, "mcap": {"skipped": without_mcap}}}


def _replay_rows(f: Result) -> list[Row]:
    r = f["replay"]
    rows = [
        (f"replay ({r['samples']} samples, file read)", f"{r['replay_per_s'] / 1e6:.2f} M/s [{r['replay_min_per_s'] / 1e6:.2f}-{r['replay_max_per_s'] / 1e6:.2f}]",
         f"streaming {r['stream_per_s'] / 1e3:.0f} k/s",
         f"{r['ratio']:.0f}x (>= 1 M/s{met(r['replay_per_s'] >= 1e6)}; >= 20x{met(r['ratio'] >= 20)})")
    ]  # fmt: skip
    if "mcap" in r:
        rows.append(("replay from MCAP (same samples)", f"skipped, {r['mcap']['skipped']}", "", ""))
    else:
        rows.append(
            ("replay from MCAP (same samples)", f"{r['mcap_replay_per_s'] / 1e6:.2f} M/s", f"JSON lines {r['replay_per_s'] / 1e6:.2f} M/s",
             f"{r['mcap_over_jsonl']:.2f}x (>= 1 M/s{met(r['mcap_replay_per_s'] >= 1e6)})")
        )  # fmt: skip
    return rows


def _calibration_rows(f: Result) -> list[Row]:
    c = f["calibration"]
    return [
        (f"batch odometry, parsed columns ({c['samples']})",
         f"{c['batch_per_s'] / 1e6:.1f} M/s; 1 % dropouts + 0.5 % spikes {c['batch_faulty_per_s'] / 1e6:.1f} M/s; fit evaluation {c['evaluation_per_s'] / 1e6:.1f} M/s",
         "-", f"(>= 10 M/s{met(c['batch_per_s'] >= 10e6)}; evaluation{met(c['evaluation_per_s'] >= 10e6)})"),
        ("calibration of a 2 m square pair", f"{1000 * c['fit_s']:.0f} ms ({c['fit_steps']} steps, {c['fit_evaluations']} evaluations)", "-", "report"),
    ]  # fmt: skip


def _arbiter_rows(f: Result) -> list[Row]:
    a = f["arbiter"]
    return [
        ("arbiter per command (5 sources)", f"{a['arbiter_us']:.2f} us", f"core cmd_vel handling {a['core_us']:.2f} us", f"{100 * a['arbiter_share']:.0f}% of it (report)"),
        ("arbiter per command (+3 locks)", f"{a['arbiter_locks_us']:.2f} us", f"core cmd_vel handling {a['core_us']:.2f} us", f"{100 * a['arbiter_locks_share']:.0f}% of it (report)"),
    ]  # fmt: skip


REPLAY = Figure("replay", "replay throughput", "replay throughput against the streaming path ...", ("replay",), _replay, _replay_rows)
CALIBRATION = Figure("calibration", "calibration speed", "calibration: the batch odometry on parsed columns, one fit ...", ("calibration",),
                     lambda plan, out: {"calibration": calibration_speed(plan.pick(200_000, 2_000_000))}, _calibration_rows)  # fmt: skip
ARBITER = Figure("arbiter", "arbiter cost", "the arbiter's cost per command, against the gateway core's whole cmd_vel handling ...", ("arbiter",),
                 lambda plan, out: {"arbiter": arbiter_cost(plan.pick(5_000, 50_000))}, _arbiter_rows)  # fmt: skip
