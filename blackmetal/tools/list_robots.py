"""``blackmetal robots``: the robots whose gateway is alive (liveliness ``**/alive/gateway``), one row each.

Each row: the prefix, the robot link (control/log), the poll rate, the pose
(x, y, yaw), the e-stop and the command source that drives, from the
gateway's health and the odometry's pose. On a terminal (or with --table) a
table; piped, one prefix a line, for scripts; --json, every row as JSON.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from dataclasses import dataclass
from typing import Any

import msgspec
import zenoh

from blackmetal.runtime.zenoh_setup import add_zenoh_arguments
from blackmetal.schemas import ANY_GATEWAY_ALIVE, GatewayHealth, Keys, Pose, ZenohUnreachable

from .client import connect, first_reply, tool

#: How often the router is tried again while --wait lasts.
RETRY_S = 0.2
#: Tokens are collected at least this long once connected (a router that came up late still gets its answers).
MIN_COLLECT_S = 1.0
#: Once tokens have come, the list is complete when this long passes without a new one.
QUIET_S = 0.5
#: How long the health and pose queries of the rows may take (all are asked at once).
QUERY_S = 2.0


def alive_robots(session: zenoh.Session, timeout: float = 5.0, expect: int = 0) -> list[str]:
    """Prefixes with a live gateway, from a liveliness subscriber with history (an early ``get`` can miss tokens the
    router has not yet told a new session): until ``expect`` (or one) came and QUIET_S passed without a new one."""
    prefixes: set[str] = set()
    subscriber = session.liveliness().declare_subscriber(ANY_GATEWAY_ALIVE, history=True)
    try:
        deadline = time.monotonic() + timeout
        last_new = -math.inf
        while (left := deadline - time.monotonic()) > 0 and (len(prefixes) < max(expect, 1) or time.monotonic() - last_new < QUIET_S):
            if (sample := subscriber.try_recv()) is None:
                time.sleep(min(0.02, left))
            elif sample.kind == zenoh.SampleKind.PUT and (prefix := Keys.prefix_of_gateway_token(str(sample.key_expr))) not in prefixes:
                prefixes.add(prefix)
                last_new = time.monotonic()
    finally:
        subscriber.undeclare()
    return sorted(prefixes, key=natural)


def natural(prefix: str) -> list[Any]:
    """Sort key: ``fleet/r2`` before ``fleet/r10``."""
    return [int(chunk) if index % 2 else chunk for index, chunk in enumerate(re.split(r"(\d+)", prefix))]


@dataclass(frozen=True, slots=True)
class RobotRow:
    """One live robot: its gateway's health and its odometry's pose (None: no answer)."""

    prefix: str
    health: GatewayHealth | None
    pose: Pose | None

    def as_json(self) -> dict[str, Any]:
        h, p = self.health, self.pose
        return {
            "prefix": self.prefix,
            "link": None if h is None else {"control": h.control.state, "log": h.log.state},
            "poll_hz": None if h is None else h.poll_hz,
            "pose": None if p is None else {"x": p.x, "y": p.y, "yaw": p.yaw},
            "estop": None if h is None else h.estop,
            "active_source": None if h is None else h.active_source,
            "health": None if h is None else msgspec.to_builtins(h),
        }


HEADER = ("prefix", "link (control/log)", "poll", "x (m)", "y (m)", "yaw (°)", "e-stop", "drives")
RIGHT = {2, 3, 4, 5}  # numbers


def _cells(row: RobotRow) -> tuple[str, ...]:
    h, p = row.health, row.pose
    link, poll, estop, drives = ("no health", "-", "-", "-")
    if h is not None:
        link, poll = f"{h.control.state}/{h.log.state}", f"{h.poll_hz:.0f} Hz"
        estop, drives = ("ENGAGED" if h.estop else "off"), (h.active_source or "-")
    pose = ("-", "-", "-") if p is None else (f"{p.x:+.3f}", f"{p.y:+.3f}", f"{math.degrees(p.yaw):+.1f}")
    return (row.prefix, link, poll, *pose, estop, drives)


def table(rows: list[RobotRow]) -> str:
    lines = [HEADER, *(_cells(row) for row in rows)]
    widths = [max(len(line[k]) for line in lines) for k in range(len(HEADER))]
    return "\n".join(
        "  ".join(cell.rjust(w) if k in RIGHT else cell.ljust(w) for k, (cell, w) in enumerate(zip(line, widths, strict=True))).rstrip()
        for line in lines
    )


@tool("robots")
def run(args: argparse.Namespace) -> int:
    deadline = time.monotonic() + args.wait
    while True:  # a router that comes up before the deadline is still met (scripts start it just before)
        try:
            _, settings, session = connect(args)
            break
        except ZenohUnreachable:
            if time.monotonic() + RETRY_S > deadline:
                raise
        time.sleep(RETRY_S)
    output = "json" if args.json else "table" if args.table or sys.stdout.isatty() else "prefixes"
    with session:
        robots = alive_robots(session, max(deadline - time.monotonic(), MIN_COLLECT_S), args.expect)
        # the rows' queries may take what is left of --wait (at least QUERY_S): a loaded gateway answers late, not never
        query_s = max(QUERY_S, deadline - time.monotonic())
        # every query is sent before any answer is awaited; piped prefixes need none
        wanted = robots if output != "prefixes" else []
        asked = [(p, session.get(Keys(p).health, timeout=query_s), session.get(Keys(p).pose, timeout=query_s)) for p in wanted]
        rows = [RobotRow(p, first_reply(health, GatewayHealth), first_reply(pose, Pose)) for p, health, pose in asked]
    if output == "json":
        print(json.dumps([row.as_json() for row in rows]))
    if not robots:
        print(f"blackmetal robots: no live gateway found via {settings.where()} within {args.wait:g} s", file=sys.stderr)
        return 1
    if output == "table":
        print(table(rows))
    elif output == "prefixes":
        print("\n".join(robots))
    return 0


def build_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--wait", type=float, default=5.0, help="seconds to reach the router and collect answers (default 5, like every tool)"
    )
    parser.add_argument(
        "--expect", type=int, default=0, metavar="N",
        help="wait (up to --wait) until N robots are alive, e.g. while a fleet starts (default: answer once those present have)",
    )  # fmt: skip
    shape = parser.add_mutually_exclusive_group()
    shape.add_argument("--table", action="store_true", help="the table even when the output is not a terminal (piped: one prefix a line)")
    shape.add_argument("--json", action="store_true", help="one JSON array: per robot its prefix, link, poll rate, pose, e-stop, "
                       "active source and the whole health")  # fmt: skip
    add_zenoh_arguments(parser)
