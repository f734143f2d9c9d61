"""``blackmetal watch``: a live view of pose, status, health, the navigation's goal and errors."""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections import deque

import zenoh

from blackmetal.runtime.signals import stop_on_signals
from blackmetal.schemas import ErrorReport, GatewayHealth, LinkHealth, NavFeedback, Pose, RobotStatus

from .client import Latest, add_client_arguments, connect, decoded, decoded_replies, require_gateway, tool


def _fmt_pose(pose: Pose | None) -> str:
    if pose is None:
        return "-"
    return f"x={pose.x:+8.3f} m  y={pose.y:+8.3f} m  yaw={math.degrees(pose.yaw):+7.2f}°  v={pose.v:+.3f} m/s  w={pose.w:+.3f} rad/s"


def _link(link: LinkHealth) -> str:
    """A link's state, with why it is not connected (``connecting: cannot connect to ...: Connection refused``)."""
    return link.state if link.reason is None or link.state == "connected" else f"{link.state}: {link.reason}"


def recent_errors(session: zenoh.Session, key: str, timeout: float) -> list[ErrorReport]:
    """The reports every service on ``key`` still keeps (each answers a get with its latest), oldest first."""
    replies = session.get(key, consolidation=zenoh.ConsolidationMode.NONE, timeout=min(timeout, 2.0))
    return sorted(decoded_replies(replies, ErrorReport), key=lambda report: report.stamp)


def describe_sources(health: GatewayHealth) -> str:
    """Who drives, who else spoke lately (age, dropped commands), and the locks: one line for people."""
    heard = sorted(
        ((name, s) for name, s in health.sources.items() if s.age is not None and s.age < 10.0), key=lambda item: -item[1].priority
    )
    parts = [f"{health.active_source or 'nobody'} drives"]
    parts += [f"{name} ({s.priority}) {s.age:.1f} s ago, {s.dropped} dropped" for name, s in heard if name != health.active_source]
    engaged = [name for name, on in health.locks.items() if on]
    if health.locks:
        parts.append("locks: " + (", ".join(f"{name} ENGAGED" for name in engaged) if engaged else "all released"))
    return "; ".join(parts)


def describe_goal(feedback: NavFeedback) -> str:
    """The navigation's latest goal, one line: its state, where to, how far and how long left, why it ended."""
    goal = feedback.goal
    where = f"({goal.x:.3f}, {goal.y:.3f}, {math.degrees(goal.yaw):.1f}°) in {goal.frame}"
    if feedback.state.done:
        why = f": {feedback.reason}" if feedback.reason else ""
        return f"goal {feedback.goal_id[:8]} to {where} {feedback.state.value} after {feedback.elapsed:.1f} s{why}"
    return (f"goal {feedback.goal_id[:8]} to {where} {feedback.state.value}: {feedback.distance_remaining:.3f} m left, "
            f"eta {feedback.eta:.1f} s, {feedback.elapsed:.1f} s so far")  # fmt: skip


def render(pose: Pose | None, truth: Pose | None, status: RobotStatus | None, health: GatewayHealth | None,
           errors: list[ErrorReport], pose_rate: float, nav: NavFeedback | None = None) -> list[str]:  # fmt: skip
    lines = [f"pose    {_fmt_pose(pose)}   ({pose_rate:.0f}/s)"]
    if truth is not None:
        lines.append(f"truth   {_fmt_pose(truth)}")
    lines.append("status  -" if status is None else f"status  {status.state_name} ({status.state}), direction {status.direction_name}")
    if health is None:
        lines.append("health  -")
    else:
        h = health
        rtt = "-" if h.last_rtt_ms is None else f"{h.last_rtt_ms:.2f} ms"
        lines += [
            f"health  control {_link(h.control)} (reconnects {h.control.reconnects}), log {_link(h.log)}; "
            f"poll {h.poll_hz:.1f} Hz, rtt {rtt}; e-stop {'ENGAGED' if h.estop else 'off'}; "
            f"{'idle (cmd timeout)' if h.cmd_timeout_active else 'commanded'}",
            f"drivers {describe_sources(h)}",
            f"counts  commands {h.commands_sent}, polls {h.polls}, replies {h.replies}, full-buffer {h.full_buffer}, "
            f"malformed {h.malformed_replies}, rejected inputs {h.rejected_inputs}, keep-alives {h.keepalives}",
        ]
    if nav is not None:
        lines.append(f"nav     {describe_goal(nav)}")
    lines.append(f"errors  {len(errors)} recent" + ("" if errors else ": none"))
    for report in errors[-5:]:
        lines.append(f"  {time.strftime('%H:%M:%S', time.localtime(report.stamp))} {report.source} {report.key}: {report.reason}")
    return lines


@tool("watch")
def run(args: argparse.Namespace) -> int:
    keys, settings, session = connect(args)
    stop = stop_on_signals()
    with session:
        # --duration bounds the whole run, the wait for a gateway included
        health0 = require_gateway(session, keys, settings, min(args.wait, args.duration) if args.duration else args.wait)
        pose = Latest(session, keys.pose, Pose)
        truth = Latest(session, keys.sim_truth, Pose)
        status = Latest(session, keys.status, RobotStatus)
        health = Latest(session, keys.health, GatewayHealth, health0)
        nav = Latest(session, keys.nav_feedback, NavFeedback)
        errors: deque[ErrorReport] = deque(maxlen=50)

        def on_error(sample: zenoh.Sample) -> None:
            if (report := decoded(ErrorReport, sample)) is not None:
                errors.append(report)

        session.declare_subscriber(keys.errors, on_error)
        errors.extend(recent_errors(session, keys.errors, args.wait))  # what went wrong before this watch started
        tty = sys.stdout.isatty()
        period = 0.2 if tty else 1.0
        deadline = time.monotonic() + args.duration if args.duration else math.inf
        last_count, last_time = 0, time.monotonic()
        print(f"blackmetal watch on {keys.prefix} via {settings.where()} (Ctrl-C to quit)", flush=True)
        while True:  # at once (what is known already, recent errors included), then every period, and at the end
            now = time.monotonic()
            rate = (pose.count - last_count) / max(now - last_time, 1e-6)
            last_count, last_time = pose.count, now
            text = "\n".join(render(pose.value, truth.value, status.value, health.value, list(errors), rate, nav.value))
            sys.stdout.write(f"\x1b[H\x1b[J{text}\n" if tty else f"{text}\n--\n")
            sys.stdout.flush()
            if now >= deadline or stop.wait(min(period, max(deadline - now, 0.0))):
                break
    return 0


def build_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--duration", type=float, default=0.0, help="quit after this many seconds (default: run until Ctrl-C)")
    add_client_arguments(parser)
