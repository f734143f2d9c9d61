"""``blackmetal bench``: the gateway's and odometry's figures, each next to a baseline from the same run.

| figure | baseline in the same run |
|---|---|
| cmd_vel put -> bytes at the robot socket, p50/p99 | one plain Zenoh hop between two Python processes |
| e-stop put -> EMG_STOP at the robot socket, p50/p99 | cmd_vel's figure |
| ROS 2 /cmd_vel (CDR, rmw_zenoh key) through ``blackmetal ros2`` -> robot socket: publisher -> adapter -> gateway, and routed publisher -> gateway -> adapter -> gateway | cmd_vel's figure and one Zenoh hop |
| /odom samples per second from ``blackmetal ros2`` at 100 Hz polling | poses per second in the same window |
| impulse reply at the gateway -> Pose at a client | two Zenoh hops (a ping-pong round trip) |
| sustained poll rate and worst gap at 100 and 200 Hz | the asked rate |
| replay samples/s, file reading included | the streaming pipeline on the same file |
| resident memory after 60 s at 100 Hz | a bare Python process with zenoh imported |
| gateway CPU at 100 Hz polling | - |
| cmd_vel flood (5 kHz for 5 s) | memory before the flood; the latency target |

Latency figures are measured in several rounds, the baseline in each round
right before the figure and paced like it (an idle machine wakes up slower);
medians are reported with min and max, and a figure whose rounds disagree by
more than 2x is marked noisy. Nothing is asserted:
this measures, the tests assert behaviour.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from typing import Any

from . import figures, peers


def _spread(values: list[float]) -> dict[str, float]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def _noisy(values: list[float]) -> bool:
    return len(values) > 1 and min(values) > 0 and max(values) / min(values) > 2.0


def measure(quick: bool, progress: Any = print) -> dict[str, Any]:
    rounds = 1 if quick else 3
    samples = 40 if quick else 200
    # --quick proves every figure still runs end to end (the smoke test); its windows are as short as
    # that allows, and its figures mean nothing. Warm-ups: before a window, once the gateway polls.
    warmup = 0.3 if quick else None
    warmups: dict[str, float] = {} if warmup is None else {"warmup": warmup}
    out: dict[str, Any] = {"quick": quick, "rounds": rounds}

    progress("latency: cmd_vel -> robot socket, against one Zenoh hop ...")
    hops, cmds, hop_p99, cmd_p99 = [], [], [], []
    rtts, poses, rtt_p99, pose_p99 = [], [], [], []
    for _ in range(rounds):
        hop = peers.zenoh_hop(samples)
        cmd = figures.cmd_latency(samples)
        hops.append(hop["p50_ms"])
        hop_p99.append(hop["p99_ms"])
        cmds.append(cmd["p50_ms"])
        cmd_p99.append(cmd["p99_ms"])
    out["zenoh_hop_ms"] = {"p50": _spread(hops), "p99": _spread(hop_p99)}
    out["cmd_vel_to_robot_ms"] = {
        "p50": _spread(cmds),
        "p99": _spread(cmd_p99),
        "p50_over_hop": statistics.median(c / h for c, h in zip(cmds, hops, strict=False)),
        "noisy": _noisy(cmds) or _noisy(hops),
    }
    progress("latency: ROS 2 /cmd_vel through blackmetal ros2 -> robot socket, against cmd_vel and one Zenoh hop ...")
    for name, in_line in (("ros2_cmd_vel_to_robot_ms", True), ("ros2_routed_cmd_vel_to_robot_ms", False)):
        ros_cmds, ros_p99 = [], []
        for _ in range(rounds):
            ros = figures.cmd_latency(samples, via_ros2=True, ros2_in_line=in_line)
            ros_cmds.append(ros["p50_ms"])
            ros_p99.append(ros["p99_ms"])
        extra = statistics.median(ros_cmds) - statistics.median(cmds)
        out[name] = {
            "p50": _spread(ros_cmds),
            "p99": _spread(ros_p99),
            "p50_over_cmd_vel": statistics.median(ros_cmds) / statistics.median(cmds),
            "extra_hops": extra / statistics.median(hops),
        }
    progress("ROS 2 /odom rate at 100 Hz polling, against the pose rate ...")
    out["ros2_odom"] = figures.ros2_odom_rate(0.5 if quick else 10.0, **warmups)
    progress("latency: e-stop -> EMG_STOP at the robot socket, against cmd_vel ...")
    estops = [figures.estop_latency(samples // 2) for _ in range(rounds)]
    out["estop_to_robot_ms"] = {
        "p50": _spread([e["p50_ms"] for e in estops]),
        "p99": _spread([e["p99_ms"] for e in estops]),
        "p50_over_cmd_vel": statistics.median(e["p50_ms"] for e in estops) / statistics.median(cmds),
    }
    progress("latency: impulse reply -> Pose at a client, against two Zenoh hops ...")
    for _ in range(rounds):
        # the baseline paced like the polls (50 Hz): the same idle time between samples
        two = peers.zenoh_hop(samples // 2, gap=(0.019, 0.021))
        pose = figures.pose_latency(0.5 if quick else 4.0)
        rtts.append(two["rtt_p50_ms"])
        rtt_p99.append(two["rtt_p99_ms"])
        poses.append(pose["p50_ms"])
        pose_p99.append(pose["p99_ms"])
    out["two_hops_ms"] = {"p50": _spread(rtts), "p99": _spread(rtt_p99)}
    out["impulse_to_pose_ms"] = {
        "p50": _spread(poses),
        "p99": _spread(pose_p99),
        "p50_over_two_hops": statistics.median(poses) / statistics.median(rtts),
        "noisy": _noisy(poses) or _noisy(rtts),
    }
    progress("poll rate at 100 and 200 Hz ...")
    out["poll"] = {str(int(hz)): figures.poll_rate(hz, 0.5 if quick else 5.0, **warmups) for hz in (100.0, 200.0)}
    progress("replay throughput against the streaming path ...")
    out["replay"] = figures.replay_throughput(50_000 if quick else 1_000_000, 5_000 if quick else 100_000)
    progress("calibration: the batch odometry on parsed columns, one fit ...")
    out["calibration"] = figures.calibration_speed(200_000 if quick else 2_000_000)
    progress("recorder CPU and bytes/s at 100 and 200 Hz ...")
    out["recorder"] = {str(int(hz)): figures.recorder_load(hz, 0.5 if quick else 10.0, **warmups) for hz in (100.0, 200.0)}
    progress(f"memory and CPU after {1 if quick else 60} s at 100 Hz ...")
    out["memory"] = figures.memory_and_cpu(1.0 if quick else 60.0, **warmups)
    progress("cmd_vel flood ...")
    out["flood"] = figures.flood(5000.0, 0.3 if quick else 5.0)
    return out


def table(f: dict[str, Any]) -> str:
    def ms(spread: dict[str, float]) -> str:
        return f"{spread['median']:.3f} ms [{spread['min']:.3f}-{spread['max']:.3f}]"

    def met(ok: bool) -> str:
        return ": met" if ok else ": MISSED"

    cmd, hop = f["cmd_vel_to_robot_ms"], f["zenoh_hop_ms"]
    pose, two = f["impulse_to_pose_ms"], f["two_hops_ms"]
    rows = [
        ("figure", "measured (median [min-max])", "baseline, same run", "ratio / target"),
        (
            "cmd_vel -> robot socket p50",
            ms(cmd["p50"]),
            f"1 Zenoh hop {ms(hop['p50'])}",
            f"{cmd['p50_over_hop']:.2f}x (<= 1.5x{met(cmd['p50_over_hop'] <= 1.5)})" + (" NOISY" if cmd["noisy"] else ""),
        ),
        ("cmd_vel -> robot socket p99", ms(cmd["p99"]), f"1 Zenoh hop {ms(hop['p99'])}", f"(<= 1 ms{met(cmd['p99']['median'] <= 1.0)})"),
        (
            "e-stop -> EMG_STOP at robot p50",
            ms(f["estop_to_robot_ms"]["p50"]),
            f"cmd_vel p50 {ms(cmd['p50'])}",
            f"{f['estop_to_robot_ms']['p50_over_cmd_vel']:.2f}x (<= 1x{met(f['estop_to_robot_ms']['p50_over_cmd_vel'] <= 1.0)})",
        ),
        ("e-stop -> EMG_STOP at robot p99", ms(f["estop_to_robot_ms"]["p99"]), f"cmd_vel p99 {ms(cmd['p99'])}", ""),
        (
            "impulse -> Pose at client p50",
            ms(pose["p50"]),
            f"2 Zenoh hops {ms(two['p50'])}",
            f"{pose['p50_over_two_hops']:.2f}x (<= 1.5x{met(pose['p50_over_two_hops'] <= 1.5)})" + (" NOISY" if pose["noisy"] else ""),
        ),
        ("impulse -> Pose at client p99", ms(pose["p99"]), f"2 Zenoh hops {ms(two['p99'])}", ""),
    ]
    ros = f["ros2_cmd_vel_to_robot_ms"]
    rows.append(
        ("ROS /cmd_vel -> robot p50 (ros2 in line)", ms(ros["p50"]), f"cmd_vel p50 {ms(cmd['p50'])}",
         f"{ros['p50_over_cmd_vel']:.2f}x; +{ros['extra_hops']:.2f} Zenoh hops (<= 1 more hop{met(ros['extra_hops'] <= 1.0)})")
    )  # fmt: skip
    rows.append(("ROS /cmd_vel -> robot p99 (ros2 in line)", ms(ros["p99"]), f"cmd_vel p99 {ms(cmd['p99'])}", ""))
    routed = f["ros2_routed_cmd_vel_to_robot_ms"]
    rows.append(
        ("ROS /cmd_vel -> robot p50, routed via the gateway", ms(routed["p50"]), f"cmd_vel p50 {ms(cmd['p50'])}",
         f"{routed['p50_over_cmd_vel']:.2f}x; +{routed['extra_hops']:.2f} Zenoh hops (report: two more transits by construction)")
    )  # fmt: skip
    o = f["ros2_odom"]
    rows.append(
        ("/odom rate at 100 Hz polling", f"{o['odom_hz']:.1f} Hz; adapter CPU {o['adapter_cpu_pct']:.1f}%", f"pose {o['pose_hz']:.1f} Hz",
         f"{100 * o['ratio']:.1f}% (= pose rate{met(abs(o['ratio'] - 1) <= 0.01)})")
    )  # fmt: skip
    for hz, p in f["poll"].items():
        rows.append(
            (f"poll at {hz} Hz", f"{p['rate_hz']:.1f} Hz, worst gap {p['worst_gap_ms']:.1f} ms", f"asked {hz} Hz",
             f"{100 * p['ratio']:.1f}% (>= 98%), gap {p['worst_gap_periods']:.2f} periods (<= 3){met(p['ratio'] >= 0.98 and p['worst_gap_periods'] <= 3)}")
        )  # fmt: skip
    r = f["replay"]
    rows.append(
        (f"replay ({r['samples']} samples, file read)", f"{r['replay_per_s'] / 1e6:.2f} M/s [{r['replay_min_per_s'] / 1e6:.2f}-{r['replay_max_per_s'] / 1e6:.2f}]",
         f"streaming {r['stream_per_s'] / 1e3:.0f} k/s",
         f"{r['ratio']:.0f}x (>= 1 M/s{met(r['replay_per_s'] >= 1e6)}; >= 20x{met(r['ratio'] >= 20)})")
    )  # fmt: skip
    rows.append(
        ("replay from MCAP (same samples)", f"{r['mcap_replay_per_s'] / 1e6:.2f} M/s", f"JSON lines {r['replay_per_s'] / 1e6:.2f} M/s",
         f"{r['mcap_over_jsonl']:.2f}x (>= 1 M/s{met(r['mcap_replay_per_s'] >= 1e6)})")
    )  # fmt: skip
    c = f["calibration"]
    rows.append(
        (f"batch odometry, parsed columns ({c['samples']})",
         f"{c['batch_per_s'] / 1e6:.1f} M/s; 1 % dropouts + 0.5 % spikes {c['batch_faulty_per_s'] / 1e6:.1f} M/s; fit evaluation {c['evaluation_per_s'] / 1e6:.1f} M/s",
         "-", f"(>= 10 M/s{met(c['batch_per_s'] >= 10e6)}; evaluation{met(c['evaluation_per_s'] >= 10e6)})")
    )  # fmt: skip
    rows.append((
        "calibration of a 2 m square pair", f"{1000 * c['fit_s']:.0f} ms ({c['fit_steps']} steps, {c['fit_evaluations']} evaluations)", "-", "report"
    ))  # fmt: skip
    for hz, rec in f["recorder"].items():
        rows.append(
            (f"recorder at {hz} Hz polling", f"CPU {rec['cpu_pct']:.1f}% of a core, {rec['bytes_per_s'] / 1e3:.1f} kB/s", "-", "report")
        )
    m = f["memory"]
    rows.append(
        (f"RSS after {m['seconds']:.0f} s at 100 Hz", f"gateway {m['gateway_mb']:.1f} MB, odometry {m['odometry_mb']:.1f} MB",
         f"bare zenoh {m['bare_zenoh_mb']:.1f} MB", f"+{m['gateway_over_bare_mb']:.1f} / +{m['odometry_over_bare_mb']:.1f} MB (<= +40 MB{met(max(m['gateway_over_bare_mb'], m['odometry_over_bare_mb']) <= 40)})")
    )  # fmt: skip
    rows.append(("CPU at 100 Hz", f"gateway {m['gateway_cpu_pct']:.1f}%, odometry {m['odometry_cpu_pct']:.1f}% of a core", "-", "report"))
    fl = f["flood"]
    rows.append(
        (f"cmd_vel flood {fl['sent_hz'] / 1e3:.1f} kHz", f"RSS {fl['rss_before_mb']:.1f} -> {fl['rss_after_mb']:.1f} MB; last command after {fl['last_command_latency_ms']:.2f} ms",
         "memory before the flood", f"{fl['rss_growth_mb']:+.1f} MB; {fl['commands_at_robot']} of {fl['sent']} puts sent on (latest wins)")
    )  # fmt: skip
    widths = [max(len(row[i]) for row in rows) for i in range(4)]
    lines = [" | ".join(cell.ljust(widths[i]) for i, cell in enumerate(row)) for row in rows]
    lines.insert(1, "-+-".join("-" * w for w in widths))
    return "\n".join(lines)


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="blackmetal bench", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="seconds instead of minutes; for smoke tests, not for figures")
    parser.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    return parser


def run(args: argparse.Namespace) -> int:
    started = time.monotonic()
    result = measure(args.quick, progress=lambda text: print(text, file=sys.stderr, flush=True))
    result["duration_s"] = time.monotonic() - started
    print(table(result))
    print(f"(took {result['duration_s']:.0f} s)")
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(result, handle, indent=2, default=lambda x: None if isinstance(x, float) and math.isnan(x) else x)
    return 0
