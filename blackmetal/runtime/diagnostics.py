"""The one diagnostics severity table: which condition is OK, WARN, ERROR or STALE, with its words. Pure.

The ROS 2 adapter's and the Foxglove view's ``/diagnostics`` once disagreed (an engaged e-stop ERROR in one, WARN in
the other); both read their levels and texts here.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from enum import IntEnum


class Level(IntEnum):
    """diagnostic_msgs/DiagnosticStatus levels; a higher one is worse."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


#: One condition that holds: its level and its reason in words.
Check = tuple[Level, str]


@dataclass(frozen=True, slots=True)
class Status:
    level: Level
    name: str
    message: str
    hardware_id: str = ""
    values: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True, slots=True)
class Condition:
    """One row of the table: a condition's level and its text (a ``str.format`` template); a graded one (a rate, a
    round trip, a count) takes its ``severe`` level past its second threshold."""

    level: Level
    text: str
    severe: Level | None = None

    def check(self, severe: bool = False, **fields: object) -> Check:
        level = self.severe if severe and self.severe is not None else self.level
        return level, self.text.format(**fields)


def worst(name: str, hardware_id: str, checks: Iterable[Check], ok: str, values: Iterable[tuple[str, str]] = ()) -> Status:
    """The status of ``checks``: the worst level, their reasons worst first (``ok`` when there are none)."""
    ordered = sorted(checks, key=lambda c: -int(c[0]))
    level = ordered[0][0] if ordered else Level.OK
    message = "; ".join(reason for _, reason in ordered) if ordered else ok
    return Status(level, name, message, hardware_id, tuple(values))


# The gateway, as both views show it.
#: The e-stop is engaged: nothing moves until a person releases it.
ESTOP_ENGAGED = Condition(Level.ERROR, "e-stop engaged{origin}")
#: Another gateway runs on the same prefix: this one refuses commands.
CONFLICT = Condition(Level.ERROR, "another gateway ({other}) on {prefix}: commands refused")
COMMANDS_REFUSED = Condition(Level.ERROR, "refused: another gateway ({other}) on this prefix")
#: The control link (commands, polls) is not connected: the robot cannot be driven.
CONTROL_LINK_DOWN = Condition(Level.ERROR, "control link {state}")
#: The log link is not connected: the robot still drives, its log is lost.
LOG_LINK_DOWN = Condition(Level.WARN, "log link {state}")
#: Replies lost or malformed since the gateway started (the Foxglove view's "gateway: robot exchange").
REPLIES_LOST_EVER = Level.WARN

# The ROS 2 adapter's robot link, from the gateway's health and liveliness.
#: Counting windows for lost replies, rejected samples, bad ROS inputs and failed calls (s).
WINDOW_S = 10.0
GATEWAY_NOT_RUNNING = Condition(Level.ERROR, "the gateway is not running (no {key})")
NO_HEALTH_YET = Condition(Level.STALE, "no gateway health yet on {key}")
#: STALE after this long without a health report (the gateway reports every 1 s).
HEALTH_STALE_S = 3.0
HEALTH_STALE = Condition(Level.STALE, "no gateway health for {age:.1f} s")
#: WARN / ERROR when the measured poll rate is below this fraction of the asked one.
POLL_WARN_RATIO = 0.9
POLL_ERROR_RATIO = 0.5
POLL_SLOW = Condition(Level.WARN, "polling at {hz:g} Hz of {asked:g} Hz", severe=Level.ERROR)
#: WARN / ERROR when the last round trip is longer (ms); the gateway gives a request up after 500 ms.
RTT_WARN_MS = 100.0
RTT_ERROR_MS = 250.0
ROUND_TRIP_SLOW = Condition(Level.WARN, "round trip {ms:.0f} ms", severe=Level.ERROR)
#: ERROR when at least this fraction of the polls of the window lost their reply (any: WARN).
LOST_ERROR_FRACTION = 0.1
REPLIES_LOST = Condition(Level.WARN, "{lost} of {polls} replies lost in {window:g} s", severe=Level.ERROR)

# The ROS 2 adapter's odometry, from the poses, the odometry's reports and liveliness.
ODOMETRY_NOT_RUNNING = Condition(Level.ERROR, "the odometry is not running (no {key})")
NO_POSE_YET = Condition(Level.STALE, "no pose yet on {key}")
#: WARN when the last pose is older than this (s), STALE beyond POSE_STALE_S.
POSE_LATE_S = 0.5
POSE_LATE = Condition(Level.WARN, "last pose {age:.1f} s ago")
POSE_STALE_S = 2.0
POSE_STALE = Condition(Level.STALE, "no pose for {age:.1f} s")
#: ERROR at this many rejected samples in the window (any: WARN); 25 in 10 s is 5 % at 50 Hz.
REJECTED_ERROR_COUNT = 25
SAMPLES_REJECTED = Condition(Level.WARN, "{count} impulse samples rejected in {window:g} s", severe=Level.ERROR)

# The ROS 2 adapter itself.
BAD_ROS_INPUTS = Condition(Level.WARN, "{count} bad ROS inputs in {window:g} s (reported on {key})")
CALLS_FAILED = Condition(Level.WARN, "{count} service calls failed in {window:g} s")


def link_level(state: str) -> Level:
    """A link to the robot, by its state: connected is OK, connecting WARN, anything else ERROR."""
    return {"connected": Level.OK, "connecting": Level.WARN}.get(state, Level.ERROR)
