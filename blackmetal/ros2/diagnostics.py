"""ROS 2 ``/diagnostics``: the three statuses (robot link, odometry, adapter) from the latest of what the node saw.

The latest health, pose, odometry reports and liveliness it was fed,
turned into three ``DiagnosticStatus`` every :data:`DIAGNOSTICS_PERIOD_S`
by the thresholds below (the README lists them). Pure, ``now`` passed in.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from blackmetal.schemas import ErrorReport, GatewayHealth, Keys

from .options import Ros2Options
from .ros_types import Diagnostic, Level

DIAGNOSTICS_PERIOD_S = 1.0
#: Counting windows for lost replies, rejected samples, bad ROS inputs and failed calls (s).
WINDOW_S = 10.0
#: Robot link: STALE after this long without a health report (the gateway reports every 1 s).
HEALTH_STALE_S = 3.0
#: Robot link: WARN / ERROR when the measured poll rate is below this fraction of the asked one.
POLL_WARN_RATIO = 0.9
POLL_ERROR_RATIO = 0.5
#: Robot link: WARN / ERROR when the last round trip is longer (ms); the gateway gives a request up after 500 ms.
RTT_WARN_MS = 100.0
RTT_ERROR_MS = 250.0
#: Robot link: ERROR when at least this fraction of the polls of the window lost their reply (any: WARN).
LOST_ERROR_FRACTION = 0.1
#: Odometry: WARN when the last pose is older than this (s), STALE beyond POSE_STALE_S.
POSE_LATE_S = 0.5
POSE_STALE_S = 2.0
#: Odometry: ERROR at this many rejected samples in the window (any: WARN); 25 in 10 s is 5 % at 50 Hz.
REJECTED_ERROR_COUNT = 25


class WindowCount:
    """Events counted over the last :data:`WINDOW_S` seconds, and in all."""

    def __init__(self, window: float = WINDOW_S) -> None:
        self.window = window
        self.total = 0
        self._events: deque[tuple[float, int]] = deque()

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


# ------------------------------------------------------------------ diagnostics
def _yes(value: bool | None) -> str:
    return "unknown" if value is None else ("yes" if value else "no")


def _status(name: str, hardware_id: str, checks: list[tuple[Level, str]], ok: str, values: list[tuple[str, str]]) -> Diagnostic:
    """The worst level of ``checks`` and their reasons, worst first (``ok`` when there are none)."""
    checks = sorted(checks, key=lambda c: -int(c[0]))
    level = checks[0][0] if checks else Level.OK
    message = "; ".join(reason for _, reason in checks) if checks else ok
    return Diagnostic(level, name, message, hardware_id, tuple(values))


class Diagnostics:
    """The three statuses of ``/diagnostics`` from what it was fed last; pure, ``now`` passed in."""

    def __init__(self, keys: Keys, node: str, expected_poll_hz: float) -> None:
        self.keys = keys
        self.label = node.lstrip("/") or node
        self.expected_poll_hz = expected_poll_hz
        self.health: GatewayHealth | None = None
        self.health_at = -math.inf
        self._lost: deque[tuple[float, int, int]] = deque()  # (now, lost replies, polls) of each health
        self.gateway_alive: bool | None = None
        self.odometry_alive: bool | None = None
        self.pose_at = -math.inf
        self.poses = 0
        self.rejected = WindowCount()
        self.last_rejection = ""

    # inputs
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
        if who == "gateway":
            self.gateway_alive = alive
        elif who == "odometry":
            self.odometry_alive = alive

    # statuses
    def lost_in_window(self, now: float) -> tuple[int, int]:
        """(replies lost, polls) over the health reports of the last window."""
        while len(self._lost) > 1 and self._lost[0][0] <= now - WINDOW_S:
            self._lost.popleft()
        if len(self._lost) < 2:
            return 0, 0
        (_, lost0, polls0), (_, lost1, polls1) = self._lost[0], self._lost[-1]
        return max(0, lost1 - lost0), max(0, polls1 - polls0)

    def robot_link(self, now: float) -> Diagnostic:
        h, age = self.health, now - self.health_at
        name, hw = f"{self.label}: robot link", self.keys.prefix
        values = [("gateway alive", _yes(self.gateway_alive)), ("health age (s)", f"{age:.1f}" if h else "never")]
        if self.gateway_alive is False:
            return _status(name, hw, [(Level.ERROR, f"the gateway is not running (no {self.keys.alive_gateway})")], "", values)
        if h is None:
            return _status(name, hw, [(Level.STALE, f"no gateway health yet on {self.keys.health}")], "", values)
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
        if age > HEALTH_STALE_S:
            return _status(name, hw, [(Level.STALE, f"no gateway health for {age:.1f} s")], "", values)
        checks: list[tuple[Level, str]] = []
        if h.control.state != "connected":
            checks.append((Level.ERROR, f"control link {h.control.state}"))
        else:
            ratio = h.poll_hz / self.expected_poll_hz
            if ratio < POLL_WARN_RATIO:
                level = Level.ERROR if ratio < POLL_ERROR_RATIO else Level.WARN
                checks.append((level, f"polling at {h.poll_hz:g} Hz of {self.expected_poll_hz:g} Hz"))
        if h.conflict_with:
            checks.append((Level.ERROR, f"another gateway ({h.conflict_with}) on {self.keys.prefix}: commands refused"))
        if h.log.state != "connected":
            checks.append((Level.WARN, f"log link {h.log.state}"))
        if h.estop:
            checks.append((Level.WARN, f"e-stop engaged{h.estop_origin()}"))
        if h.last_rtt_ms is not None and h.last_rtt_ms > RTT_WARN_MS:
            checks.append((Level.ERROR if h.last_rtt_ms > RTT_ERROR_MS else Level.WARN, f"round trip {h.last_rtt_ms:.0f} ms"))
        if lost:
            level = Level.ERROR if lost >= LOST_ERROR_FRACTION * max(polls, 1) else Level.WARN
            checks.append((level, f"{lost} of {polls} replies lost in {WINDOW_S:g} s"))
        return _status(name, hw, checks, f"connected, polling at {h.poll_hz:g} Hz", values)

    def odometry(self, now: float) -> Diagnostic:
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
            return _status(name, hw, [(Level.ERROR, f"the odometry is not running (no {self.keys.alive_odometry})")], "", values)
        if not self.poses:
            return _status(name, hw, [(Level.STALE, f"no pose yet on {self.keys.pose}")], "", values)
        if age > POSE_STALE_S:
            return _status(name, hw, [(Level.STALE, f"no pose for {age:.1f} s")], "", values)
        checks: list[tuple[Level, str]] = []
        if age > POSE_LATE_S:
            checks.append((Level.WARN, f"last pose {age:.1f} s ago"))
        if recent:
            level = Level.ERROR if recent >= REJECTED_ERROR_COUNT else Level.WARN
            checks.append((level, f"{recent} impulse samples rejected in {WINDOW_S:g} s"))
        return _status(name, hw, checks, "publishing poses", values)

    def adapter(self, now: float, stats: AdapterStats, options: Ros2Options, pending: int) -> Diagnostic:
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
        checks: list[tuple[Level, str]] = []
        if bad:
            checks.append((Level.WARN, f"{bad} bad ROS inputs in {WINDOW_S:g} s (reported on {self.keys.errors})"))
        if failed:
            checks.append((Level.WARN, f"{failed} service calls failed in {WINDOW_S:g} s"))
        return _status(f"{self.label}: ROS 2 adapter", self.keys.prefix, checks, f"running; calibration {options.calibration}", values)
