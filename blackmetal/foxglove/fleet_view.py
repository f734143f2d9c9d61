"""A fleet in one view (``--fleet``): one :class:`~.live.LiveView` per robot, and the fleet's summary and log.

Apart from the live view because the summary has a clock and a notion of a robot lost, which one robot's view has not.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from blackmetal.robot_model import Encoders
from blackmetal.schemas import ErrorReport, GatewayHealth, Keys, Pose

from .channels import ChannelFactory, Kind, array, foxglove_channel, message_schema, obj, report_log, timestamp, typed
from .live import LiveView
from .naming import FLEET_NAMESPACE

#: A robot whose gateway's health (published once a second) has not arrived for this long (s, the view's clock) is lost.
LOST_AFTER_S = 2.5
#: The fleet summary goes out at most this often on health alone (s); a robot lost or back sends it at once.
SUMMARY_PERIOD_S = 1.0
#: The topics that follow every robot's health (and so the robots lost and back).
FLEET_TOPICS = frozenset({f"{FLEET_NAMESPACE}/summary", f"{FLEET_NAMESPACE}/log"})

_STRING, _NUMBER_OR_NULL = typed("string"), typed(["number", "null"])
FLEET_SUMMARY_SCHEMA = message_schema(
    "FleetSummary",
    "blackmetal: one row per robot of the fleet, from each <prefix>/gateway/health, its liveliness and <prefix>/pose",
    {
        "stamp": typed("number", description="the newest health's stamp"),
        "robots_up": typed("integer", description="robots with a fresh health and both links connected"),
        "lost": array(_STRING, description="ids of the robots lost (no health, or its gateway gone)"),
        "estop": array(_STRING, description="ids of the robots whose e-stop is engaged"),
        "driving": typed("object", additionalProperties=_STRING, description="id -> the command source that drives it"),
        "robots": array(
            obj(
                id=_STRING,
                prefix=_STRING,
                link=typed("string", description="control/log link states, 'no health', or 'lost: <why>'"),
                health_age=typed(["number", "null"], description="s since its last health arrived"),
                poll_hz=typed("number"),
                estop=typed(["boolean", "null"]),
                active_source=typed(["string", "null"], description="who drives (null: nobody)"),
                conflict_with=typed(["string", "null"]),
                x=_NUMBER_OR_NULL,
                y=_NUMBER_OR_NULL,
                yaw=_NUMBER_OR_NULL,
            )
        ),
    },
)


@dataclass(slots=True)
class RobotRow:
    """What the fleet summary knows of one robot: its last health (and when it arrived), its pose, its gateway's token."""

    id: str
    prefix: str
    health: GatewayHealth | None = None
    pose: Pose | None = None
    #: When its last health arrived (the view's clock); None: none since the summary was last watched.
    seen: float | None = None
    #: Why it is lost ("" while it is not).
    lost: str = ""


@dataclass(frozen=True, slots=True)
class Presence:
    """A robot lost or back, and why: what the fleet's log says and why the summary goes out at once."""

    robot_id: str
    lost: bool
    reason: str


class FleetSummary:
    """The fleet at a glance, one row per robot; pure, ``now`` passed in. Lost and back as docs/foxglove.md says."""

    def __init__(self, robots: list[tuple[str, str]]) -> None:
        """``robots``: (id, prefix) in the fleet file's order."""
        self.rows = {robot_id: RobotRow(robot_id, prefix) for robot_id, prefix in robots}
        self._newest = -math.inf

    def _lose(self, row: RobotRow, reason: str) -> Presence | None:
        row.seen = None
        if row.lost:
            return None
        row.lost = reason
        return Presence(row.id, True, reason)

    def on_health(self, robot_id: str, health: GatewayHealth, now: float) -> Presence | None:
        row = self.rows[robot_id]
        row.health, row.seen = health, now
        self._newest = max(self._newest, health.stamp)
        if row.lost:
            row.lost = ""
            return Presence(robot_id, False, "its gateway's health arrives again")
        return None

    def on_token(self, robot_id: str, alive: bool, now: float) -> Presence | None:
        """Its gateway's liveliness token appeared or went: gone is lost at once; present waits for a health."""
        return None if alive else self._lose(self.rows[robot_id], "its gateway left (liveliness token gone)")

    def on_pose(self, robot_id: str, pose: Pose) -> None:
        self.rows[robot_id].pose = pose

    def tick(self, now: float) -> list[Presence]:
        """Robots whose health stopped arriving."""
        changes = []
        for row in self.rows.values():
            if row.seen is not None and now >= row.seen + LOST_AFTER_S:
                change = self._lose(row, f"no health for {LOST_AFTER_S:g} s")
                if change is not None:
                    changes.append(change)
        return changes

    def next_deadline(self) -> float:
        return min((row.seen + LOST_AFTER_S for row in self.rows.values() if row.seen is not None), default=math.inf)

    def suspend(self) -> None:
        """Nobody follows health: forget when it last came, so no robot is lost for a silence nobody listened to."""
        for row in self.rows.values():
            row.seen = None

    def message(self, now: float) -> dict[str, Any]:
        rows = []
        for row in self.rows.values():
            h = row.health
            fresh = h if not row.lost and row.seen is not None else None
            if row.lost:
                link = f"lost: {row.lost}"
            else:
                link = "no health" if fresh is None else f"{fresh.control.state}/{fresh.log.state}"
            rows.append(
                {
                    "id": row.id,
                    "prefix": row.prefix,
                    "link": link,
                    "health_age": None if row.seen is None else max(now - row.seen, 0.0),
                    "poll_hz": 0.0 if fresh is None else fresh.poll_hz,
                    "estop": None if h is None else h.estop,
                    "active_source": None if fresh is None else fresh.active_source,
                    "conflict_with": None if h is None else h.conflict_with,
                    **{axis: getattr(row.pose, axis, None) for axis in ("x", "y", "yaw")},
                }
            )
        return {
            "stamp": self._newest if self._newest > -math.inf else 0.0,
            "robots_up": sum(1 for r in rows if r["link"] == "connected/connected"),
            "lost": [row.id for row in self.rows.values() if row.lost],
            "estop": [r["id"] for r in rows if r["estop"]],
            "driving": {r["id"]: r["active_source"] for r in rows if r["active_source"]},
            "robots": rows,
        }


class FleetView:
    """One :class:`LiveView` per robot under ``/<id>/`` (frames ``<id>/...`` on one ``/tf``), ``/fleet/summary`` and ``/fleet/log``.

    The summary's poses are each robot's latest, read when it is made (``poses``), never a stream.
    """

    def __init__(
        self,
        robots: list[tuple[str, Keys, Encoders | None, int]],
        clock: Callable[[], float] = time.monotonic,
        channel: ChannelFactory = foxglove_channel,
        poses: Callable[[str], bytes | None] = lambda robot_id: None,
    ) -> None:
        """``robots``: (id, keys, its encoders or None for the defaults, its path length), in the fleet file's order;
        ``poses(id)``: the robot's latest pose payload, if the host holds one."""
        self.clock = clock
        self.poses = poses
        self.tf = channel("/tf", Kind.TRANSFORM, None)  # one tree for the fleet, as ros2 --fleet sends every robot's to the absolute /tf
        self.views = {
            robot_id: LiveView(keys, robot_id, path_length, encoders, tf=self.tf, channel=channel)
            for robot_id, keys, encoders, path_length in robots
        }
        self.summary = FleetSummary([(robot_id, keys.prefix) for robot_id, keys, _, _ in robots])
        self.summary_channel = channel(f"{FLEET_NAMESPACE}/summary", Kind.JSON, FLEET_SUMMARY_SCHEMA)
        #: Robots lost and back, and refusals of client messages that name no robot (a topic outside every /<id>/, the server's own).
        self.log = channel(f"{FLEET_NAMESPACE}/log", Kind.LOG, None)
        self._last_summary = -math.inf

    def feeds(self) -> dict[str, set[str]]:
        """Every robot's keys -> the topics they feed; each health also feeds the summary and the fleet's log."""
        feeds: dict[str, set[str]] = {}
        for view in self.views.values():
            for key, topics in view.feeds().items():
                feeds.setdefault(key, set()).update(topics)
            feeds[view.keys.health] |= FLEET_TOPICS
        return feeds

    def handlers(self, robot_id: str) -> dict[str, Callable[[bytes], None]]:
        view = self.views[robot_id]
        handlers = view.handlers()
        show_health = handlers[view.keys.health]

        def on_health(payload: bytes) -> None:
            show_health(payload)
            if not (self.summary_channel.has_sinks() or self.log.has_sinks()):
                return
            health = view._decode(GatewayHealth, payload)
            if health is None:
                return
            now = self.clock()
            change = self.summary.on_health(robot_id, health, now)
            if change is not None or now >= self._last_summary + SUMMARY_PERIOD_S:
                self._changed([change] if change is not None else [], now)

        handlers[view.keys.health] = on_health
        return handlers

    def on_token(self, robot_id: str, alive: bool) -> None:
        now = self.clock()
        change = self.summary.on_token(robot_id, alive, now)
        if change is not None:
            self._changed([change], now)

    def tick(self, now: float) -> None:
        changes = self.summary.tick(now)
        if changes:
            self._changed(changes, now)

    def next_deadline(self) -> float:
        return self.summary.next_deadline()

    def _changed(self, changes: list[Presence], now: float) -> None:
        from foxglove.messages import Log, LogLevel

        if self.log.has_sinks():
            for change in changes:
                level, word = (LogLevel.Error, "lost") if change.lost else (LogLevel.Info, "back")
                message = f"{change.robot_id} {word}: {change.reason}"
                self.log.log(Log(timestamp=timestamp(time.time()), level=level, message=message, name="fleet"))
        if self.summary_channel.has_sinks():
            for robot_id, view in self.views.items():
                payload = self.poses(robot_id)
                pose = view._decode(Pose, payload) if payload is not None else None
                if pose is not None:
                    self.summary.on_pose(robot_id, pose)
            self._last_summary = now
            self.summary_channel.log(json.dumps(self.summary.message(now)).encode())

    def on_fleet_error(self, report: ErrorReport) -> None:
        self.log.log(report_log(report))
