"""ROS 2 ``/diagnostics``: three statuses (robot link, odometry, adapter) from the latest of what the node saw.

Levels, words and thresholds are the shared table's (:mod:`blackmetal.runtime.diagnostics`). Pure, ``now`` passed in.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from blackmetal.runtime import diagnostics as table
from blackmetal.runtime.diagnostics import WINDOW_S, Check, Status, worst
from blackmetal.schemas import ErrorReport, GatewayHealth, Keys

from .options import Ros2Options

DIAGNOSTICS_PERIOD_S = 1.0


@dataclass(slots=True)
class WindowCount:
    """Events counted over the last :data:`WINDOW_S` seconds, and in all."""

    window: float = WINDOW_S
    total: int = 0
    _events: deque[tuple[float, int]] = field(default_factory=deque)

    def add(self, now: float, count: int = 1) -> None:
        self._events.append((now, count))
        self.total += count

    def recent(self, now: float) -> int:
        while self._events and self._events[0][0] <= now - self.window:
            self._events.popleft()
        return sum(count for _, count in self._events)


@dataclass(slots=True)
class AdapterStats:
    """What the adapter itself did, for its diagnostic status."""

    commands: int = 0
    estops: int = 0
    bad_inputs: WindowCount = field(default_factory=WindowCount)
    confirmed: int = 0
    failed: WindowCount = field(default_factory=WindowCount)


def _yes(value: bool | None) -> str:
    return "unknown" if value is None else ("yes" if value else "no")


@dataclass(slots=True)
class Diagnostics:
    """The three statuses of ``/diagnostics`` from what it was fed last; pure, ``now`` passed in."""

    keys: Keys
    node: str
    expected_poll_hz: float
    health: GatewayHealth | None = None
    health_at: float = -math.inf
    gateway_alive: bool | None = None
    odometry_alive: bool | None = None
    pose_at: float = -math.inf
    poses: int = 0
    rejected: WindowCount = field(default_factory=WindowCount)
    last_rejection: str = ""
    _lost: deque[tuple[float, int, int]] = field(default_factory=deque)  # (now, lost replies, polls) of each health

    @property
    def label(self) -> str:
        return self.node.lstrip("/") or self.node

    def on_health(self, health: GatewayHealth, now: float) -> None:
        if self.health is not None and health.source != self.health.source:
            self._lost.clear()  # another gateway run: its counters start over
        self.health, self.health_at = health, now
        self._lost.append((now, health.lost_replies, health.polls))

    def on_pose(self, now: float) -> None:
        self.pose_at = now
        self.poses += 1

    def on_error_report(self, report: ErrorReport, now: float) -> None:
        """The odometry's reports on the impulses key are its rejected (or repaired) samples."""
        if report.source == "odometry" and report.key == self.keys.impulses:
            self.rejected.add(now, max(1, report.suppressed))  # a rate-limit summary stands for its suppressed reports
            self.last_rejection = report.reason

    def on_alive(self, who: str, alive: bool) -> None:
        """``who``: ``gateway`` or ``odometry``."""
        setattr(self, f"{who}_alive", alive)

    def lost_in_window(self, now: float) -> tuple[int, int]:
        """(replies lost, polls) over the health reports of the last window."""
        while len(self._lost) > 1 and self._lost[0][0] <= now - WINDOW_S:
            self._lost.popleft()
        if len(self._lost) < 2:
            return 0, 0
        (_, lost0, polls0), (_, lost1, polls1) = self._lost[0], self._lost[-1]
        return max(0, lost1 - lost0), max(0, polls1 - polls0)

    def robot_link(self, now: float) -> Status:
        h, age = self.health, now - self.health_at
        name, hw = f"{self.label}: robot link", self.keys.prefix
        values = [("gateway alive", _yes(self.gateway_alive)), ("health age (s)", f"{age:.1f}" if h else "never")]
        if self.gateway_alive is False:
            return worst(name, hw, [table.GATEWAY_NOT_RUNNING.check(key=self.keys.alive_gateway)], "", values)
        if h is None:
            return worst(name, hw, [table.NO_HEALTH_YET.check(key=self.keys.health)], "", values)
        lost, polls = self.lost_in_window(now)
        values += [
            ("control link", h.control.state),
            ("log link", h.log.state),
            ("poll rate (Hz)", f"{h.poll_hz:g}"),
            ("asked poll rate (Hz)", f"{self.expected_poll_hz:g}"),
            ("round trip (ms)", "none" if h.last_rtt_ms is None else f"{h.last_rtt_ms:.1f}"),
            ("lost replies", str(h.lost_replies)),
            (f"lost replies ({WINDOW_S:g} s)", str(lost)),
            ("e-stop", "engaged" if h.estop else "released"),
            ("e-stop since", h.estop_since_text()),
            ("e-stop by", h.estop_by or ""),
            ("command timeout active", _yes(h.cmd_timeout_active)),
            ("active source", h.active_source or "none"),
        ]
        if age > table.HEALTH_STALE_S:
            return worst(name, hw, [table.HEALTH_STALE.check(age=age)], "", values)
        checks: list[Check] = []
        if h.control.state != "connected":
            checks.append(table.CONTROL_LINK_DOWN.check(state=h.control.state))
        elif (ratio := h.poll_hz / self.expected_poll_hz) < table.POLL_WARN_RATIO:
            checks.append(table.POLL_SLOW.check(ratio < table.POLL_ERROR_RATIO, hz=h.poll_hz, asked=self.expected_poll_hz))
        if h.conflict_with:
            checks.append(table.CONFLICT.check(other=h.conflict_with, prefix=self.keys.prefix))
        if h.log.state != "connected":
            checks.append(table.LOG_LINK_DOWN.check(state=h.log.state))
        if h.estop:
            checks.append(table.ESTOP_ENGAGED.check(origin=h.estop_origin()))
        if h.last_rtt_ms is not None and h.last_rtt_ms > table.RTT_WARN_MS:
            checks.append(table.ROUND_TRIP_SLOW.check(h.last_rtt_ms > table.RTT_ERROR_MS, ms=h.last_rtt_ms))
        if lost:
            severe = lost >= table.LOST_ERROR_FRACTION * max(polls, 1)
            checks.append(table.REPLIES_LOST.check(severe, lost=lost, polls=polls, window=WINDOW_S))
        return worst(name, hw, checks, f"connected, polling at {h.poll_hz:g} Hz", values)

    def odometry(self, now: float) -> Status:
        age = now - self.pose_at
        recent = self.rejected.recent(now)
        name, hw = f"{self.label}: odometry", self.keys.prefix
        values = [
            ("odometry alive", _yes(self.odometry_alive)),
            ("pose age (s)", f"{age:.2f}" if self.poses else "never"),
            ("poses", str(self.poses)),
            (f"rejected samples ({WINDOW_S:g} s)", str(recent)),
            ("rejected samples", str(self.rejected.total)),
            ("last rejection", self.last_rejection or "none"),
        ]
        if self.odometry_alive is False:
            return worst(name, hw, [table.ODOMETRY_NOT_RUNNING.check(key=self.keys.alive_odometry)], "", values)
        if not self.poses:
            return worst(name, hw, [table.NO_POSE_YET.check(key=self.keys.pose)], "", values)
        if age > table.POSE_STALE_S:
            return worst(name, hw, [table.POSE_STALE.check(age=age)], "", values)
        checks: list[Check] = []
        if age > table.POSE_LATE_S:
            checks.append(table.POSE_LATE.check(age=age))
        if recent:
            checks.append(table.SAMPLES_REJECTED.check(recent >= table.REJECTED_ERROR_COUNT, count=recent, window=WINDOW_S))
        return worst(name, hw, checks, "publishing poses", values)

    def adapter(self, now: float, stats: AdapterStats, options: Ros2Options, pending: int) -> Status:
        bad, failed = stats.bad_inputs.recent(now), stats.failed.recent(now)
        values = [
            ("flavor", options.flavor),
            ("distro", options.distro),
            ("node", options.node),
            ("domain id", str(options.domain_id)),
            ("cmd_vel to", self.keys.cmd_vel_of(options.source)),
            ("commands forwarded", str(stats.commands)),
            ("e-stops forwarded", str(stats.estops)),
            (f"bad ROS inputs ({WINDOW_S:g} s)", str(bad)),
            ("bad ROS inputs", str(stats.bad_inputs.total)),
            ("service calls confirmed", str(stats.confirmed)),
            ("service calls failed", str(stats.failed.total)),
            ("service calls pending", str(pending)),
            ("calibration", options.calibration),
            ("odometry covariance", options.covariance),
            ("robot model", "published (robot_description, tf_static, wheels on tf)" if options.robot else "not published"),
        ]
        checks: list[Check] = []
        if bad:
            checks.append(table.BAD_ROS_INPUTS.check(count=bad, window=WINDOW_S, key=self.keys.errors))
        if failed:
            checks.append(table.CALLS_FAILED.check(count=failed, window=WINDOW_S))
        return worst(f"{self.label}: ROS 2 adapter", self.keys.prefix, checks, f"running; calibration {options.calibration}", values)
