"""``blackmetal bench``: the gateway's and odometry's figures, each next to a baseline from the same run.

| figure | baseline in the same run |
|---|---|
| cmd_vel put -> bytes at the robot socket, p50/p99 | one plain Zenoh hop between two Python processes |
| e-stop put -> EMG_STOP at the robot socket, p50/p99 | cmd_vel's figure |
| e-stop while three processes flood cmd_vel/nav at full speed, p50/p99/max | <= 100 ms in every sample |
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

``--only`` measures some figures (and the figures they need as baselines).
A figure whose optional extra is not installed (the ROS 2 figures need
``ros2``, the recorder and the MCAP replay ``record``) is skipped with one
line saying what to install, and the rest still runs; a figure that fails
says why in one line, and the rest still runs. The table and the JSON say
which figures were skipped or failed. However the bench ends, a figure
failing, SIGTERM or Ctrl-C, every process it started is stopped first.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import statistics
import subprocess
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from blackmetal.runtime.harness import ChildFailed
from blackmetal.schemas import BlackmetalError, MissingExtra, require_extra

from . import children, figures, peers

#: The modules each optional extra brings, as the commands that need them check them.
EXTRA_MODULES: dict[str, tuple[str, ...]] = {"ros2": ("rosbags", "xxhash"), "record": ("mcap",)}


def missing_extra(extra: str) -> str | None:
    """Why a figure cannot run without ``extra`` (what to install), or None when it is installed."""
    for module in EXTRA_MODULES[extra]:
        try:
            require_extra("blackmetal bench", extra, module)
        except MissingExtra:
            return f"needs the {extra} extra: pip install 'blackmetal[{extra}]'"
    return None


def _spread(values: list[float]) -> dict[str, float]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def _noisy(values: list[float]) -> bool:
    return len(values) > 1 and min(values) > 0 and max(values) / min(values) > 2.0


@dataclass(frozen=True)
class Plan:
    """How long and how often every figure measures."""

    quick: bool
    progress: Callable[[str], object]

    @property
    def rounds(self) -> int:
        return 1 if self.quick else 3

    @property
    def samples(self) -> int:
        return 40 if self.quick else 200

    @property
    def warmups(self) -> dict[str, float]:
        # --quick proves every figure still runs end to end (the smoke test); its windows are as short as
        # that allows, and its figures mean nothing. Warm-ups: before a window, once the gateway polls.
        return {"warmup": 0.3} if self.quick else {}

    def seconds(self, quick: float, full: float) -> float:
        return quick if self.quick else full

    def count(self, quick: int, full: int) -> int:
        return quick if self.quick else full


def _cmd_vel(plan: Plan, out: dict[str, Any]) -> dict[str, Any]:
    hops, cmds, hop_p99, cmd_p99 = [], [], [], []
    for _ in range(plan.rounds):
        hop = peers.zenoh_hop(plan.samples)
        cmd = figures.cmd_latency(plan.samples)
        hops.append(hop["p50_ms"])
        hop_p99.append(hop["p99_ms"])
        cmds.append(cmd["p50_ms"])
        cmd_p99.append(cmd["p99_ms"])
    return {
        "zenoh_hop_ms": {"p50": _spread(hops), "p99": _spread(hop_p99)},
        "cmd_vel_to_robot_ms": {
            "p50": _spread(cmds),
            "p99": _spread(cmd_p99),
            "p50_over_hop": statistics.median(c / h for c, h in zip(cmds, hops, strict=False)),
            "noisy": _noisy(cmds) or _noisy(hops),
        },
    }


def _ros2_cmd_vel(plan: Plan, out: dict[str, Any]) -> dict[str, Any]:
    cmd_p50, hop_p50 = out["cmd_vel_to_robot_ms"]["p50"]["median"], out["zenoh_hop_ms"]["p50"]["median"]
    result = {}
    for name, in_line in (("ros2_cmd_vel_to_robot_ms", True), ("ros2_routed_cmd_vel_to_robot_ms", False)):
        ros_cmds, ros_p99 = [], []
        for _ in range(plan.rounds):
            ros = figures.cmd_latency(plan.samples, via_ros2=True, ros2_in_line=in_line)
            ros_cmds.append(ros["p50_ms"])
            ros_p99.append(ros["p99_ms"])
        result[name] = {
            "p50": _spread(ros_cmds),
            "p99": _spread(ros_p99),
            "p50_over_cmd_vel": statistics.median(ros_cmds) / cmd_p50,
            "extra_hops": (statistics.median(ros_cmds) - cmd_p50) / hop_p50,
        }
    return result


def _ros2_odom(plan: Plan, out: dict[str, Any]) -> dict[str, Any]:
    return {"ros2_odom": figures.ros2_odom_rate(plan.seconds(0.5, 10.0), **plan.warmups)}


def _estop(plan: Plan, out: dict[str, Any]) -> dict[str, Any]:
    estops = [figures.estop_latency(plan.samples // 2) for _ in range(plan.rounds)]
    return {
        "estop_to_robot_ms": {
            "p50": _spread([e["p50_ms"] for e in estops]),
            "p99": _spread([e["p99_ms"] for e in estops]),
            "p50_over_cmd_vel": statistics.median(e["p50_ms"] for e in estops) / out["cmd_vel_to_robot_ms"]["p50"]["median"],
        }
    }


def _estop_flood(plan: Plan, out: dict[str, Any]) -> dict[str, Any]:
    return {"estop_under_flood_ms": figures.estop_under_flood(plan.count(10, 100))}


def _pose(plan: Plan, out: dict[str, Any]) -> dict[str, Any]:
    rtts, poses, rtt_p99, pose_p99 = [], [], [], []
    for _ in range(plan.rounds):
        # the baseline paced like the polls (50 Hz): the same idle time between samples
        two = peers.zenoh_hop(plan.samples // 2, gap=(0.019, 0.021))
        pose = figures.pose_latency(plan.seconds(0.5, 4.0))
        rtts.append(two["rtt_p50_ms"])
        rtt_p99.append(two["rtt_p99_ms"])
        poses.append(pose["p50_ms"])
        pose_p99.append(pose["p99_ms"])
    return {
        "two_hops_ms": {"p50": _spread(rtts), "p99": _spread(rtt_p99)},
        "impulse_to_pose_ms": {
            "p50": _spread(poses),
            "p99": _spread(pose_p99),
            "p50_over_two_hops": statistics.median(poses) / statistics.median(rtts),
            "noisy": _noisy(poses) or _noisy(rtts),
        },
    }


def _poll(plan: Plan, out: dict[str, Any]) -> dict[str, Any]:
    return {"poll": {str(int(hz)): figures.poll_rate(hz, plan.seconds(0.5, 5.0), **plan.warmups) for hz in (100.0, 200.0)}}


def _replay(plan: Plan, out: dict[str, Any]) -> dict[str, Any]:
    without_mcap = missing_extra("record")
    if without_mcap is not None:
        plan.progress(f"replay from MCAP: skipped, {without_mcap}")
        out["skipped"]["replay_mcap"] = without_mcap
    replay = figures.replay_throughput(plan.count(50_000, 1_000_000), plan.count(5_000, 100_000), mcap=without_mcap is None)
    return {"replay": replay if without_mcap is None else {**replay, "mcap": {"skipped": without_mcap}}}


def _calibration(plan: Plan, out: dict[str, Any]) -> dict[str, Any]:
    return {"calibration": figures.calibration_speed(plan.count(200_000, 2_000_000))}


def _arbiter(plan: Plan, out: dict[str, Any]) -> dict[str, Any]:
    return {"arbiter": figures.arbiter_cost(plan.count(5_000, 50_000))}


def _recorder(plan: Plan, out: dict[str, Any]) -> dict[str, Any]:
    return {"recorder": {str(int(hz)): figures.recorder_load(hz, plan.seconds(0.5, 10.0), **plan.warmups) for hz in (100.0, 200.0)}}


def _memory(plan: Plan, out: dict[str, Any]) -> dict[str, Any]:
    return {"memory": figures.memory_and_cpu(plan.seconds(1.0, 60.0), **plan.warmups)}


def _flood(plan: Plan, out: dict[str, Any]) -> dict[str, Any]:
    return {"flood": figures.flood(5000.0, plan.seconds(0.3, 5.0))}


@dataclass(frozen=True)
class Figure:
    """One figure (or a few measured together): what a person reads, where it goes in the result, what it needs."""

    name: str  # for --only, and in the result's "measured", "skipped" and "failed"
    title: str  # in its skip or failure line
    doing: str  # the progress line while it is measured
    keys: tuple[str, ...]  # its entries in the result
    measure: Callable[[Plan, dict[str, Any]], dict[str, Any]]
    extra: str | None = None  # the optional extra it needs (EXTRA_MODULES)
    needs: tuple[str, ...] = ()  # figures whose results are its baseline


#: Every figure, in the order they are measured.
FIGURES = (
    Figure("cmd_vel", "cmd_vel latency", "latency: cmd_vel -> robot socket, against one Zenoh hop ...",
           ("zenoh_hop_ms", "cmd_vel_to_robot_ms"), _cmd_vel),
    Figure("ros2_cmd_vel", "ROS 2 /cmd_vel latency",
           "latency: ROS 2 /cmd_vel through blackmetal ros2 -> robot socket, against cmd_vel and one Zenoh hop ...",
           ("ros2_cmd_vel_to_robot_ms", "ros2_routed_cmd_vel_to_robot_ms"), _ros2_cmd_vel, extra="ros2", needs=("cmd_vel",)),
    Figure("ros2_odom", "ROS 2 /odom rate", "ROS 2 /odom rate at 100 Hz polling, against the pose rate ...",
           ("ros2_odom",), _ros2_odom, extra="ros2"),
    Figure("estop", "e-stop latency", "latency: e-stop -> EMG_STOP at the robot socket, against cmd_vel ...",
           ("estop_to_robot_ms",), _estop, needs=("cmd_vel",)),
    Figure("estop_flood", "e-stop under a flood", "latency: e-stop while three processes flood cmd_vel/nav at full speed ...",
           ("estop_under_flood_ms",), _estop_flood),
    Figure("pose", "impulse -> Pose latency", "latency: impulse reply -> Pose at a client, against two Zenoh hops ...",
           ("two_hops_ms", "impulse_to_pose_ms"), _pose),
    Figure("poll", "poll rate", "poll rate at 100 and 200 Hz ...", ("poll",), _poll),
    Figure("replay", "replay throughput", "replay throughput against the streaming path ...", ("replay",), _replay),
    Figure("calibration", "calibration speed", "calibration: the batch odometry on parsed columns, one fit ...", ("calibration",), _calibration),
    Figure("arbiter", "arbiter cost", "the arbiter's cost per command, against the gateway core's whole cmd_vel handling ...",
           ("arbiter",), _arbiter),
    Figure("recorder", "recorder load", "recorder CPU and bytes/s at 100 and 200 Hz ...", ("recorder",), _recorder, extra="record"),
    Figure("memory", "memory and CPU", "memory and CPU at 100 Hz ...", ("memory",), _memory),
    Figure("flood", "cmd_vel flood", "cmd_vel flood ...", ("flood",), _flood),
)  # fmt: skip
FIGURE_NAMES = tuple(figure.name for figure in FIGURES)


def with_baselines(names: set[str]) -> set[str]:
    """``names`` and every figure they need as a baseline."""
    chosen = set(names)
    for figure in reversed(FIGURES):  # a figure only needs figures measured before it
        if figure.name in chosen:
            chosen.update(figure.needs)
    return chosen


def one_sentence(exc: Exception) -> str:
    """What went wrong, on one line: a child's own last line, a command's last line on stderr, or the error's text."""
    if isinstance(exc, ChildFailed):
        last = next((line.strip() for line in reversed(exc.child.lines) if line.strip()), "")
        head = str(exc).splitlines()[0].removesuffix("; its last lines:")
        return f"{head}: {last}" if last else head
    if isinstance(exc, subprocess.CalledProcessError):
        stderr = exc.stderr if isinstance(exc.stderr, str) else ""
        last = next((line.strip() for line in reversed(stderr.splitlines()) if line.strip()), "")
        return f"a helper process exited with code {exc.returncode}" + (f": {last}" if last else "")
    if isinstance(exc, BlackmetalError | OSError):
        lines = str(exc).splitlines()
        return lines[0] if lines else type(exc).__name__
    where = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
    place = f" at {Path(where.filename).name}:{where.lineno}" if where else ""
    return f"unexpected {type(exc).__name__}{place}: {exc} (a bug in the bench; please report it)"


def measure(quick: bool, progress: Callable[[str], object] = print, only: set[str] | None = None) -> dict[str, Any]:
    """Every figure (or those in ``only`` and their baselines), each next to its baseline.

    A figure whose optional extra is not installed is skipped with one line
    saying what to install; a figure that fails is reported with one line and
    the others still run. Either way its entries in the result say so
    (``{"skipped": why}``, ``{"failed": why}``), as do the result's
    ``skipped`` and ``failed``. Every child process a figure started is
    stopped when it ends, however it ends.
    """
    plan = Plan(quick, progress)
    chosen = with_baselines(only) if only is not None else set(FIGURE_NAMES)
    out: dict[str, Any] = {"quick": quick, "rounds": plan.rounds, "measured": [], "skipped": {}, "failed": {}}
    for figure in FIGURES:
        if figure.name not in chosen:
            continue
        why_not = missing_extra(figure.extra) if figure.extra else None
        for need in figure.needs:
            if why_not is None and (need in out["skipped"] or need in out["failed"]):
                why_not = f"needs the {need} figure as its baseline, which {'was skipped' if need in out['skipped'] else 'failed'}"
        if why_not is not None:
            progress(f"{figure.title}: skipped, {why_not}")
            out["skipped"][figure.name] = why_not
            out.update({key: {"skipped": why_not} for key in figure.keys})
            continue
        progress(figure.doing)
        try:
            out.update(figure.measure(plan, out))
            out["measured"].append(figure.name)
        except Exception as exc:
            failure = one_sentence(exc)
            progress(f"{figure.title}: failed, {failure}")
            out["failed"][figure.name] = failure
            out.update({key: {"failed": failure} for key in figure.keys})
        finally:
            children.stop_all()  # the net under the figure's own cleanup
    return out


Row = tuple[str, str, str, str]


def _ms(spread: dict[str, float]) -> str:
    return f"{spread['median']:.3f} ms [{spread['min']:.3f}-{spread['max']:.3f}]"


def _met(ok: bool) -> str:
    return ": met" if ok else ": MISSED"


def _cmd_vel_rows(f: dict[str, Any]) -> list[Row]:
    cmd, hop = f["cmd_vel_to_robot_ms"], f["zenoh_hop_ms"]
    p99_ratio = cmd["p99"]["median"] / hop["p99"]["median"]
    return [
        (
            "cmd_vel -> robot socket p50",
            _ms(cmd["p50"]),
            f"1 Zenoh hop {_ms(hop['p50'])}",
            f"{cmd['p50_over_hop']:.2f}x (<= 1.5x{_met(cmd['p50_over_hop'] <= 1.5)})" + (" NOISY" if cmd["noisy"] else ""),
        ),
        (
            "cmd_vel -> robot socket p99",
            _ms(cmd["p99"]),
            f"1 Zenoh hop {_ms(hop['p99'])}",
            f"{p99_ratio:.2f}x (<= 2x{_met(p99_ratio <= 2.0)}; <= 1 ms{_met(cmd['p99']['median'] <= 1.0)})",
        ),
    ]


def _estop_rows(f: dict[str, Any]) -> list[Row]:
    cmd, estop = f["cmd_vel_to_robot_ms"], f["estop_to_robot_ms"]
    return [
        (
            "e-stop -> EMG_STOP at robot p50",
            _ms(estop["p50"]),
            f"cmd_vel p50 {_ms(cmd['p50'])}",
            f"{estop['p50_over_cmd_vel']:.2f}x (<= 1x{_met(estop['p50_over_cmd_vel'] <= 1.0)})",
        ),
        ("e-stop -> EMG_STOP at robot p99", _ms(estop["p99"]), f"cmd_vel p99 {_ms(cmd['p99'])}", ""),
    ]


def _estop_flood_rows(f: dict[str, Any]) -> list[Row]:
    e = f["estop_under_flood_ms"]
    return [
        (
            f"e-stop under {e['flooders']} full-speed flooders, p50 / p99 / max",
            f"{e['p50_ms']:.2f} / {e['p99_ms']:.2f} / {e['max_ms']:.2f} ms",
            "the e-stop without a flood (above)",
            f"max <= 100 ms{_met(e['max_ms'] <= 100.0)}; {e['n']} samples, {e['lost']} without EMG_STOP",
        )
    ]


def _pose_rows(f: dict[str, Any]) -> list[Row]:
    pose, two = f["impulse_to_pose_ms"], f["two_hops_ms"]
    return [
        (
            "impulse -> Pose at client p50",
            _ms(pose["p50"]),
            f"2 Zenoh hops {_ms(two['p50'])}",
            f"{pose['p50_over_two_hops']:.2f}x (<= 1.5x{_met(pose['p50_over_two_hops'] <= 1.5)})" + (" NOISY" if pose["noisy"] else ""),
        ),
        ("impulse -> Pose at client p99", _ms(pose["p99"]), f"2 Zenoh hops {_ms(two['p99'])}", ""),
    ]


def _ros2_cmd_vel_rows(f: dict[str, Any]) -> list[Row]:
    cmd, ros, routed = f["cmd_vel_to_robot_ms"], f["ros2_cmd_vel_to_robot_ms"], f["ros2_routed_cmd_vel_to_robot_ms"]
    return [
        ("ROS /cmd_vel -> robot p50 (ros2 in line)", _ms(ros["p50"]), f"cmd_vel p50 {_ms(cmd['p50'])}",
         f"{ros['p50_over_cmd_vel']:.2f}x; +{ros['extra_hops']:.2f} Zenoh hops (<= 1 more hop{_met(ros['extra_hops'] <= 1.0)})"),
        ("ROS /cmd_vel -> robot p99 (ros2 in line)", _ms(ros["p99"]), f"cmd_vel p99 {_ms(cmd['p99'])}", ""),
        ("ROS /cmd_vel -> robot p50, routed via the gateway", _ms(routed["p50"]), f"cmd_vel p50 {_ms(cmd['p50'])}",
         f"{routed['p50_over_cmd_vel']:.2f}x; +{routed['extra_hops']:.2f} Zenoh hops (report: two more transits by construction)"),
    ]  # fmt: skip


def _ros2_odom_rows(f: dict[str, Any]) -> list[Row]:
    o = f["ros2_odom"]
    return [
        ("/odom rate at 100 Hz polling", f"{o['odom_hz']:.1f} Hz; adapter CPU {o['adapter_cpu_pct']:.1f}%", f"pose {o['pose_hz']:.1f} Hz",
         f"{100 * o['ratio']:.1f}% (= pose rate{_met(abs(o['ratio'] - 1) <= 0.01)})")
    ]  # fmt: skip


def _poll_rows(f: dict[str, Any]) -> list[Row]:
    return [
        (f"poll at {hz} Hz", f"{p['rate_hz']:.1f} Hz, worst gap {p['worst_gap_ms']:.1f} ms", f"asked {hz} Hz",
         f"{100 * p['ratio']:.1f}% (>= 98%), gap {p['worst_gap_periods']:.2f} periods (<= 3){_met(p['ratio'] >= 0.98 and p['worst_gap_periods'] <= 3)}")
        for hz, p in f["poll"].items()
    ]  # fmt: skip


def _replay_rows(f: dict[str, Any]) -> list[Row]:
    r = f["replay"]
    rows = [
        (f"replay ({r['samples']} samples, file read)", f"{r['replay_per_s'] / 1e6:.2f} M/s [{r['replay_min_per_s'] / 1e6:.2f}-{r['replay_max_per_s'] / 1e6:.2f}]",
         f"streaming {r['stream_per_s'] / 1e3:.0f} k/s",
         f"{r['ratio']:.0f}x (>= 1 M/s{_met(r['replay_per_s'] >= 1e6)}; >= 20x{_met(r['ratio'] >= 20)})")
    ]  # fmt: skip
    if "mcap" in r:
        rows.append(("replay from MCAP (same samples)", f"skipped, {r['mcap']['skipped']}", "", ""))
    else:
        rows.append(
            ("replay from MCAP (same samples)", f"{r['mcap_replay_per_s'] / 1e6:.2f} M/s", f"JSON lines {r['replay_per_s'] / 1e6:.2f} M/s",
             f"{r['mcap_over_jsonl']:.2f}x (>= 1 M/s{_met(r['mcap_replay_per_s'] >= 1e6)})")
        )  # fmt: skip
    return rows


def _calibration_rows(f: dict[str, Any]) -> list[Row]:
    c = f["calibration"]
    return [
        (f"batch odometry, parsed columns ({c['samples']})",
         f"{c['batch_per_s'] / 1e6:.1f} M/s; 1 % dropouts + 0.5 % spikes {c['batch_faulty_per_s'] / 1e6:.1f} M/s; fit evaluation {c['evaluation_per_s'] / 1e6:.1f} M/s",
         "-", f"(>= 10 M/s{_met(c['batch_per_s'] >= 10e6)}; evaluation{_met(c['evaluation_per_s'] >= 10e6)})"),
        ("calibration of a 2 m square pair", f"{1000 * c['fit_s']:.0f} ms ({c['fit_steps']} steps, {c['fit_evaluations']} evaluations)", "-", "report"),
    ]  # fmt: skip


def _arbiter_rows(f: dict[str, Any]) -> list[Row]:
    a = f["arbiter"]
    return [
        ("arbiter per command (5 sources)", f"{a['arbiter_us']:.2f} us", f"core cmd_vel handling {a['core_us']:.2f} us", f"{100 * a['arbiter_share']:.0f}% of it (report)"),
        ("arbiter per command (+3 locks)", f"{a['arbiter_locks_us']:.2f} us", f"core cmd_vel handling {a['core_us']:.2f} us", f"{100 * a['arbiter_locks_share']:.0f}% of it (report)"),
    ]  # fmt: skip


def _recorder_rows(f: dict[str, Any]) -> list[Row]:
    return [
        (f"recorder at {hz} Hz polling", f"CPU {rec['cpu_pct']:.1f}% of a core, {rec['bytes_per_s'] / 1e3:.1f} kB/s", "-", "report")
        for hz, rec in f["recorder"].items()
    ]


def _memory_rows(f: dict[str, Any]) -> list[Row]:
    m = f["memory"]
    return [
        (f"RSS after {m['seconds']:.0f} s at 100 Hz", f"gateway {m['gateway_mb']:.1f} MB, odometry {m['odometry_mb']:.1f} MB",
         f"bare zenoh {m['bare_zenoh_mb']:.1f} MB", f"+{m['gateway_over_bare_mb']:.1f} / +{m['odometry_over_bare_mb']:.1f} MB (<= +40 MB{_met(max(m['gateway_over_bare_mb'], m['odometry_over_bare_mb']) <= 40)})"),
        ("CPU at 100 Hz", f"gateway {m['gateway_cpu_pct']:.1f}%, odometry {m['odometry_cpu_pct']:.1f}% of a core", "-", "report"),
    ]  # fmt: skip


def _flood_rows(f: dict[str, Any]) -> list[Row]:
    fl = f["flood"]
    return [
        (f"cmd_vel flood {fl['sent_hz'] / 1e3:.1f} kHz", f"RSS {fl['rss_before_mb']:.1f} -> {fl['rss_after_mb']:.1f} MB; last command after {fl['last_command_latency_ms']:.2f} ms",
         "memory before the flood", f"{fl['rss_growth_mb']:+.1f} MB; {fl['commands_at_robot']} of {fl['sent']} puts sent on (latest wins)")
    ]  # fmt: skip


#: The table's rows, figure by figure, in the table's order.
ROWS: dict[str, Callable[[dict[str, Any]], list[Row]]] = {
    "cmd_vel": _cmd_vel_rows,
    "estop": _estop_rows,
    "estop_flood": _estop_flood_rows,
    "pose": _pose_rows,
    "ros2_cmd_vel": _ros2_cmd_vel_rows,
    "ros2_odom": _ros2_odom_rows,
    "poll": _poll_rows,
    "replay": _replay_rows,
    "calibration": _calibration_rows,
    "arbiter": _arbiter_rows,
    "recorder": _recorder_rows,
    "memory": _memory_rows,
    "flood": _flood_rows,
}


def table(f: dict[str, Any]) -> str:
    """The figures as a table; a skipped or failed figure is one row that says why."""
    titles = {figure.name: figure.title for figure in FIGURES}
    rows: list[Row] = [("figure", "measured (median [min-max])", "baseline, same run", "ratio / target")]
    for name, figure_rows in ROWS.items():
        if name in f["skipped"]:
            rows.append((titles[name], f"skipped, {f['skipped'][name]}", "", ""))
        elif name in f["failed"]:
            rows.append((titles[name], f"FAILED, {f['failed'][name]}", "", ""))
        elif name in f["measured"]:
            rows += figure_rows(f)
    widths = [max(len(row[i]) for row in rows) for i in range(4)]
    lines = [" | ".join(cell.ljust(widths[i]) for i, cell in enumerate(row)).rstrip() for row in rows]
    lines.insert(1, "-+-".join("-" * w for w in widths))
    return "\n".join(lines)


def _figure_names(text: str) -> set[str]:
    names = {name.strip() for name in text.split(",") if name.strip()}
    unknown = sorted(names - set(FIGURE_NAMES))
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown figure {', '.join(unknown) or repr(text)}; the figures are {', '.join(FIGURE_NAMES)}")
    return names


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="blackmetal bench", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="seconds instead of minutes; for smoke tests, not for figures")
    parser.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    parser.add_argument(
        "--only",
        metavar="FIGURE[,FIGURE]",
        type=_figure_names,
        help=f"measure only these figures (and the figures they need as baselines): {', '.join(FIGURE_NAMES)}",
    )
    parser.add_argument(
        "--fleet",
        metavar="N[,N]",
        nargs="?",
        const="1,10,50,100",
        type=_fleet_sizes,
        help="instead of the figures above: fleets of N robots on one router, one fleet gateway and odometry (default 1,10,50,100)",
    )
    parser.add_argument(
        "--views",
        action="store_true",
        help="with --fleet: also the ROS 2 and Foxglove fleet views, idle and with a client watching every robot",
    )
    return parser


def _fleet_sizes(text: str) -> list[int]:
    try:
        sizes = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"fleet sizes are whole numbers, e.g. 1,10,50,100; got {text!r}") from None
    if not sizes or min(sizes) < 1:
        raise argparse.ArgumentTypeError(f"fleet sizes are at least 1 robot each; got {text!r}")
    return sorted(set(sizes))


def _finite(value: Any) -> Any:
    """``value`` with every NaN or infinity as None (JSON has neither)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(item) for item in value]
    return value


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    """Measure, print the table, write the JSON.

    Exit codes: 0 when every figure was measured or skipped for a missing
    extra; 1 when a figure failed (the others are still measured and
    reported) or the JSON cannot be written; 2 for an unusable option;
    128 + the signal's number when SIGINT or SIGTERM stopped it. Every child
    process it started is stopped before it returns, whichever way it ends.
    """
    if args.json and not Path(args.json).resolve().parent.is_dir():
        _say(f"blackmetal bench: --json {args.json}: the folder {Path(args.json).resolve().parent} does not exist")
        return 2
    if args.views and not args.fleet:
        _say("blackmetal bench: --views measures the fleet views: give --fleet N as well")
        return 2
    with children.stopping_on_signals():  # until it returns: a signal after the measuring is only noted
        started = time.monotonic()
        result: dict[str, Any] | None = None
        try:
            if args.fleet:
                return _fleet(args, started)
            result = measure(args.quick, progress=_say, only=args.only)
        except KeyboardInterrupt:
            pass
        finally:
            children.shutdown()
        if result is None:
            stopped_by = children.stop_signal() or signal.SIGINT
            _say(f"blackmetal bench: stopped by {signal.Signals(stopped_by).name} before it finished; every process it started is stopped")
            return 128 + stopped_by
        result["duration_s"] = time.monotonic() - started
        return _report(result, args.json)


def _fleet(args: argparse.Namespace, started: float) -> int:
    """``--fleet``: one row per fleet size; a size that fails is one line, and the sizes after it are not measured."""
    from .fleet import fleet_table, measure_fleet

    if args.views:
        require_extra("blackmetal bench --fleet --views", "ros2", "rosbags")
        require_extra("blackmetal bench --fleet --views", "foxglove", "foxglove")
    try:
        runs = measure_fleet(args.fleet, args.quick, progress=_say, views=args.views)
    except (ChildFailed, TimeoutError, OSError) as exc:
        _say(f"blackmetal bench: the fleet figure failed: {one_sentence(exc)}")
        return 1
    print(fleet_table(runs))
    print(f"(took {time.monotonic() - started:.0f} s)", flush=True)
    if args.json:
        try:
            with open(args.json, "w") as handle:
                json.dump(_finite({"fleet": runs}), handle, indent=2, allow_nan=False)
        except OSError as exc:
            _say(f"blackmetal bench: cannot write {args.json}: {exc.strerror}")
            return 1
    return 0


def _report(result: dict[str, Any], json_path: str | None) -> int:
    print(table(result))
    print(f"(took {result['duration_s']:.0f} s)", flush=True)
    if json_path:
        try:
            with open(json_path, "w") as handle:
                json.dump(_finite(result), handle, indent=2, allow_nan=False)
        except OSError as exc:
            _say(f"blackmetal bench: cannot write {json_path}: {exc.strerror}")
            return 1
    if result["failed"]:
        _say(f"blackmetal bench: {len(result['failed'])} figure(s) failed ({', '.join(result['failed'])}); each says why above")
        return 1
    return 0
