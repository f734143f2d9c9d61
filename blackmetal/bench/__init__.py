"""``blackmetal bench``: the gateway's and odometry's figures, each next to a baseline from the same run.

| figure | baseline in the same run |
|---|---|
| the minimal forwarder (``forwarder``): cmd_vel put -> bytes at the robot socket, p50/p99 | one plain Zenoh hop |
| cmd_vel put -> bytes at the robot socket, p50/p99 | one plain Zenoh hop between two Python processes; the minimal forwarder |
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

Each figure is declared once, in its family's module (``command_path``,
``telemetry``, ``offline``); :mod:`.runner` measures and prints any of them.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time
from pathlib import Path
from typing import Any

from blackmetal.runtime.harness import ChildFailed
from blackmetal.schemas import require_extra

from . import children, command_path, navigation, offline, telemetry
from .runner import Figure, measure, one_sentence, table

#: Every figure, in the order they are measured (a baseline before the figures that need it).
FIGURES: tuple[Figure, ...] = (
    command_path.FORWARDER,
    command_path.CMD_VEL,
    command_path.ROS2_CMD_VEL,
    telemetry.ROS2_ODOM,
    command_path.ESTOP,
    command_path.ESTOP_FLOOD,
    telemetry.POSE,
    telemetry.POLL,
    offline.REPLAY,
    offline.CALIBRATION,
    offline.ARBITER,
    telemetry.RECORDER,
    telemetry.MEMORY,
    command_path.FLOOD,
    navigation.NAV_GOALS,
    navigation.NAV_GOALS_CALIBRATED,
    navigation.NAV_FLEET,
)
FIGURE_NAMES = tuple(figure.name for figure in FIGURES)
#: The table's order: the command path, then what the services publish, then the offline figures and the costs.
TABLE_ORDER = ("forwarder", "cmd_vel", "estop", "estop_flood", "pose", "ros2_cmd_vel", "ros2_odom", "poll", "replay",
               "calibration", "arbiter", "recorder", "memory", "flood", "nav_goals", "nav_goals_calibrated", "nav_fleet")  # fmt: skip


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

    Exit 0 when every figure was measured or skipped for a missing extra; 1 when one failed or the JSON cannot
    be written; 2 for an unusable option; 128 + the signal's number when SIGINT or SIGTERM stopped it.
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
            result = measure(FIGURES, args.quick, _say, args.only)
        except KeyboardInterrupt:
            pass
        finally:
            children.shutdown()
        if result is None:
            stopped_by = children.stop_signal() or signal.SIGINT
            _say(f"blackmetal bench: stopped by {signal.Signals(stopped_by).name} before it finished; every process it started is stopped")
            return 128 + stopped_by
        result["duration_s"] = time.monotonic() - started
        print(table({figure.name: figure for figure in FIGURES}, TABLE_ORDER, result))
        print(f"(took {result['duration_s']:.0f} s)", flush=True)
        if _write_json(result, args.json):
            return 1
        if result["failed"]:
            _say(f"blackmetal bench: {len(result['failed'])} figure(s) failed ({', '.join(result['failed'])}); each says why above")
            return 1
        return 0


def _fleet(args: argparse.Namespace, started: float) -> int:
    """``--fleet``: one row per fleet size; a size that fails is one line, and the sizes after it are not measured."""
    from .fleet import fleet_figure, fleet_table

    if args.views:
        require_extra("blackmetal bench --fleet --views", "ros2", "rosbags")
        require_extra("blackmetal bench --fleet --views", "foxglove", "foxglove")
    runs = []
    what = " and the ROS 2 and Foxglove fleet views" if args.views else ""
    try:
        for robots in args.fleet:
            _say(f"fleet of {robots}: router, {robots - 1} simulated robots and a probe, fleet gateway and odometry at 50 Hz{what} ...")
            runs.append(fleet_figure(robots, 2.0 if args.quick else 10.0, 40 if args.quick else 400, views=args.views))
    except (ChildFailed, TimeoutError, OSError) as exc:
        _say(f"blackmetal bench: the fleet figure failed: {one_sentence(exc)}")
        return 1
    print(fleet_table(runs))
    print(f"(took {time.monotonic() - started:.0f} s)", flush=True)
    return _write_json({"fleet": runs}, args.json)


def _write_json(result: dict[str, Any], json_path: str | None) -> int:
    """``result`` as JSON into ``json_path`` when given: 0, or 1 with one line when it cannot be written."""
    if json_path:
        try:
            with open(json_path, "w") as handle:
                json.dump(_finite(result), handle, indent=2, allow_nan=False)
        except OSError as exc:
            _say(f"blackmetal bench: cannot write {json_path}: {exc.strerror}")
            return 1
    return 0
