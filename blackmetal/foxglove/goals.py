"""The 3D panel's publish tools as navigation requests (pure, clock-injected); docs/foxglove.md ("Sending goals").

Foxglove's "Publish pose" sends a geometry_msgs/PoseStamped (a goal: a get on ``<prefix>/nav/goal``), "Publish pose
estimate" a PoseWithCovarianceStamped (where the robot is on the map: ``<prefix>/nav/set_pose``) and "Publish point"
a PointStamped (shown in the log, nothing moves). The navigation service's answer, accepted or rejected with its
reason, is shown on the view's ``/log`` and, when it is a refusal, as a status to the client that sent it.

A goal in the robot's own frame (the panel publishes in its display frame, ``base_link`` when it follows the robot)
is placed in ``odom`` from the odometry's pose, asked for with a get on ``<prefix>/pose`` when the goal comes.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Callable, Collection
from dataclasses import dataclass
from typing import Annotated

import msgspec

from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import (
    Keys,
    MapPose,
    NavCancel,
    NavCancelReply,
    NavGoal,
    NavGoalReply,
    PayloadError,
    Pose,
    SetPose,
    decode,
    encode,
)

from .naming import BODY_FRAMES, NavTopic, StatusLevel
from .params import Clients


class Vector(msgspec.Struct, forbid_unknown_fields=True):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


class Quaternion(msgspec.Struct, forbid_unknown_fields=True):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


class Header(msgspec.Struct):
    """std_msgs/Header as JSON; its stamp (ROS 1's ``nsec`` or ROS 2's ``nanosec``) and ``seq`` are not used."""

    frame_id: Annotated[str, msgspec.Meta(max_length=64)] = ""  # as long as a navigation frame's name may be


class RosPose(msgspec.Struct, forbid_unknown_fields=True):
    position: Vector = msgspec.field(default_factory=Vector)
    orientation: Quaternion = msgspec.field(default_factory=Quaternion)


class PoseStamped(msgspec.Struct, forbid_unknown_fields=True):
    """geometry_msgs/PoseStamped as JSON: what "Publish pose" sends (a goal)."""

    pose: RosPose
    header: Header = msgspec.field(default_factory=Header)


class PoseWithCovariance(msgspec.Struct, forbid_unknown_fields=True):
    pose: RosPose
    covariance: list[float] = []


class PoseWithCovarianceStamped(msgspec.Struct, forbid_unknown_fields=True):
    """geometry_msgs/PoseWithCovarianceStamped as JSON: what "Publish pose estimate" sends."""

    pose: PoseWithCovariance
    header: Header = msgspec.field(default_factory=Header)


class PointStamped(msgspec.Struct, forbid_unknown_fields=True):
    """geometry_msgs/PointStamped as JSON: what "Publish point" sends."""

    point: Vector
    header: Header = msgspec.field(default_factory=Header)


def yaw_of(q: Quaternion) -> float:
    """The heading of a rotation (its roll and pitch ignored); a quaternion need not be unit length, but not zero."""
    values = (q.x, q.y, q.z, q.w)
    if not all(math.isfinite(v) for v in values) or sum(v * v for v in values) < 1e-12:
        raise PayloadError("orientation", f"{values} is not a rotation (zero or not finite)")
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), q.w * q.w + q.x * q.x - q.y * q.y - q.z * q.z)


def _finite(what: str, *values: float) -> None:
    if not all(math.isfinite(v) for v in values):
        raise PayloadError(what, f"{values} is not finite")


def body_frame(frame_id: str, frame_prefix: str = "") -> bool:
    """Is ``frame_id`` the robot's own (``base_link``, ``r3/base_link``...): a pose relative to where the robot is."""
    frame = frame_id.strip().lstrip("/")
    return (frame.removeprefix(frame_prefix) if frame_prefix else frame) in BODY_FRAMES


def nav_frame(frame_id: str, frame_prefix: str = "") -> str:
    """The navigation service's frame for a header's ``frame_id``: ``odom``, or the map's name (an empty frame: ``map``).

    ``frame_prefix``: a fleet's robot's (``r3/``): ``r3/odom`` is its odom. Its body frames, and another robot's
    frames, are refused with a sentence that says which frame to set in the panel.
    """
    frame = frame_id.strip().lstrip("/")
    if not frame:
        return "map"
    local = frame.removeprefix(frame_prefix) if frame_prefix else frame
    if local == "odom":
        return "odom"
    odom = f"{frame_prefix}odom"
    if local in BODY_FRAMES:
        raise PayloadError(
            "frame",
            f"the pose is in the robot's own frame {frame!r} (the 3D panel's display frame): it is taken in map or {odom}; "
            f"set the panel's display frame to map or {odom}",
        )
    if "/" in frame:
        raise PayloadError("frame", f"{frame!r} is not this robot's map or odometry frame: publish in map or {odom}")
    return frame


def robot_of_frame(frame_id: str, robot_ids: Collection[str]) -> str | None:
    """The fleet's robot a frame names (``r3/odom`` -> ``r3``), None when it names none."""
    head, slash, _ = frame_id.strip().lstrip("/").partition("/")
    return head if slash and head in robot_ids else None


@dataclass(frozen=True, slots=True)
class NavRequest:
    """A navigation query to make: which key, its payload, and what it asks in words (for the log).

    ``relative``: a goal (x, y, yaw) in the robot's own frame; the query then asks the odometry's pose to place it.
    """

    key: str
    payload: bytes
    summary: str
    relative: tuple[float, float, float] | None = None


def placed_goal(pose: Pose, relative: tuple[float, float, float]) -> NavGoal:
    """A goal given relative to the robot, in ``odom`` from the robot's pose there."""
    x, y, yaw = relative
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    heading = math.atan2(math.sin(pose.yaw + yaw), math.cos(pose.yaw + yaw))
    return NavGoal(x=pose.x + c * x - s * y, y=pose.y + s * x + c * y, yaw=heading, frame="odom")


def _degrees(yaw: float) -> str:
    return f"{math.degrees(yaw):.0f} deg"


def request(topic: NavTopic, data: bytes, keys: Keys, frame_prefix: str = "") -> NavRequest | str:
    """The query a message on ``topic`` asks for, or (a clicked point) a line for the log.

    Raises PayloadError, for a message that decodes but asks what cannot be done too (a zero quaternion, another
    robot's frame).
    """
    if topic in (NavTopic.GOAL_POSE, NavTopic.MOVE_BASE_GOAL):
        goal = decode(PoseStamped, data)
        p = goal.pose.position
        _finite("position", p.x, p.y)
        yaw = yaw_of(goal.pose.orientation)
        if body_frame(goal.header.frame_id, frame_prefix):
            summary = f"goal ({p.x:.2f}, {p.y:.2f}) facing {_degrees(yaw)} from the robot ({goal.header.frame_id.strip()})"
            return NavRequest(keys.pose, b"", summary, relative=(p.x, p.y, yaw))
        frame = nav_frame(goal.header.frame_id, frame_prefix)
        summary = f"goal ({p.x:.2f}, {p.y:.2f}) facing {_degrees(yaw)} in {frame}"
        return NavRequest(keys.nav_goal, encode(NavGoal(x=p.x, y=p.y, yaw=yaw, frame=frame)), summary)
    if topic is NavTopic.INITIAL_POSE:
        estimate = decode(PoseWithCovarianceStamped, data)
        p = estimate.pose.pose.position
        _finite("position", p.x, p.y)
        yaw = yaw_of(estimate.pose.pose.orientation)
        frame = nav_frame(estimate.header.frame_id, frame_prefix)
        summary = f"pose estimate ({p.x:.2f}, {p.y:.2f}) facing {_degrees(yaw)} in {frame}"
        return NavRequest(keys.nav_set_pose, encode(SetPose(x=p.x, y=p.y, yaw=yaw, frame=frame)), summary)
    point = decode(PointStamped, data)
    q = point.point
    _finite("point", q.x, q.y, q.z)
    return f"clicked point ({q.x:.2f}, {q.y:.2f}, {q.z:.2f}) in {point.header.frame_id.strip() or 'no frame'}"


@dataclass(slots=True)
class NavCall:
    """A navigation query waiting for its answer: who sent it, on which topic (or service), what it asked.

    ``answer``: the host's number of the service call to answer (a cancel), None for a published message;
    ``client`` None: it left (its answer is shown on /log only, never sent to every client as a status to nobody).
    """

    client: int | None
    topic: str
    request: NavRequest
    deadline: float
    answer: int | None = None


#: Requests of one robot waiting for their answers at most: a client that floods goals gets refusals, not a flood of queries.
MAX_WAITING = 16
#: Clicked points are shown at most this often (s): a flood of them is no flood of log lines.
POINT_PERIOD_S = 0.1

#: Shows one line to the view's users (the robot's ``/log``): its level and text.
Show = Callable[[StatusLevel, str], None]
#: Refuses a client's message: ``(client, topic, reason, excerpt, now)`` -> a status to it and a report.
Refuse = Callable[[int, str, str, str, float], None]
#: Makes a query: ``(key, call, payload)``; its replies and end come back to :meth:`NavDesk.on_reply`.
Ask = Callable[[str, int, bytes], None]


def _no_show(level: StatusLevel, message: str) -> None: ...


class NavDesk:
    """One robot's navigation requests from the view's clients: made, answered, timed out; the answers shown."""

    def __init__(
        self, keys: Keys, clients: Clients, reporter: ErrorReporter, refuse: Refuse, ask: Ask, call_timeout: float, frame_prefix: str = ""
    ) -> None:
        self.keys, self.clients, self.reporter = keys, clients, reporter
        self.refuse, self.ask = refuse, ask
        self.call_timeout = call_timeout
        self.frame_prefix = frame_prefix
        #: Where the answers are shown (the robot's view's log); plugged in by the view's wiring.
        self.show: Show = _no_show
        self.calls: dict[int, NavCall] = {}
        self._numbers = itertools.count(1)
        self._last_point = -math.inf

    def on_message(self, client: int, topic: str, kind: NavTopic, data: bytes, now: float) -> None:
        try:
            asked = request(kind, data, self.keys, self.frame_prefix)
        except PayloadError as exc:
            return self.refuse(client, topic, f"{exc}; nothing was sent to the navigation service", exc.excerpt, now)
        if isinstance(asked, str):
            if not 0.0 <= now - self._last_point < POINT_PERIOD_S:
                self._last_point = now
                self.show(StatusLevel.INFO, asked)
            return None
        if len(self.calls) >= MAX_WAITING:
            return self.refuse(client, topic, self._busy(asked), "", now)
        self._send(NavCall(client, topic, asked, now + self.call_timeout))

    def _busy(self, asked: NavRequest) -> str:
        return f"{MAX_WAITING} requests already wait for the navigation service's answer; the {asked.summary} was not sent"

    def _send(self, pending: NavCall) -> None:
        call = next(self._numbers)
        self.calls[call] = pending
        self.ask(pending.request.key, call, pending.request.payload)

    def cancel(self, call: int, client: int, service: str, now: float) -> None:
        """The ``cancel_goal`` service: a get on ``<prefix>/nav/cancel`` for whatever goal runs; ``call`` answered with its reply."""
        asked = NavRequest(self.keys.nav_cancel, encode(NavCancel()), "cancel of the running goal")
        if len(self.calls) >= MAX_WAITING:
            return self.clients.answer(call, None, self._busy(asked))
        self._send(NavCall(client, service, asked, now + self.call_timeout, answer=call))

    def on_reply(self, call: int, ok: bytes | None, err: bytes | None, now: float) -> None:
        """A reply to ``call`` (``ok`` or ``err``), or its end unanswered (``None, None``); the first one counts."""
        pending = self.calls.pop(call, None)
        if pending is None:
            return
        asked = pending.request
        if ok is None and err is None:
            return self._unanswered(pending, f"no {self._service(asked)} answered on {asked.key}", now)
        if asked.relative is not None:
            return self._place(pending, ok, err, now)
        if ok is None:
            said = (err or b"").decode("utf-8", errors="replace") or "no reason given"
            return self._refused(pending, f"the navigation service refused the {asked.summary}: {said}")
        try:
            if asked.key == self.keys.nav_cancel:
                return self._canceled(pending, decode(NavCancelReply, ok))
            if asked.key == self.keys.nav_goal:
                reply = decode(NavGoalReply, ok)
                if not reply.accepted:
                    return self._refused(
                        pending, f"the navigation service rejected the {asked.summary}: {reply.reason or 'no reason given'}"
                    )
                return self.show(StatusLevel.INFO, f"{asked.summary}: accepted as {reply.goal_id}")
            placed = decode(MapPose, ok)
        except PayloadError as exc:
            return self._refused(pending, f"the navigation service answered the {asked.summary} with something else: {exc}")
        where = f"map -> odom now ({placed.x:.2f}, {placed.y:.2f}) at {_degrees(placed.yaw)}"
        self.show(StatusLevel.INFO, f"{asked.summary}: taken, {where}")

    def _place(self, pending: NavCall, ok: bytes | None, err: bytes | None, now: float) -> None:
        """The odometry's pose came for a goal relative to the robot: the goal, in odom, goes to the service now."""
        asked = pending.request
        assert asked.relative is not None
        try:
            pose = decode(Pose, ok if ok is not None else b"")
        except PayloadError as exc:
            said = (err or b"").decode("utf-8", errors="replace") if ok is None else str(exc)
            return self._refused(pending, f"the robot's pose for the {asked.summary} did not come: {said or 'no reason given'}")
        goal = placed_goal(pose, asked.relative)
        summary = f"{asked.summary}, at ({goal.x:.2f}, {goal.y:.2f}) facing {_degrees(goal.yaw or 0.0)} in odom"
        self._send(NavCall(pending.client, pending.topic, NavRequest(self.keys.nav_goal, encode(goal), summary), now + self.call_timeout))

    def _canceled(self, pending: NavCall, reply: NavCancelReply) -> None:
        said = f"canceled {', '.join(reply.canceled)}" if reply.canceled else f"nothing canceled: {reply.reason or 'no reason given'}"
        if pending.answer is not None:
            self.clients.answer(pending.answer, json.dumps({"success": bool(reply.canceled), "message": said}).encode(), None)
        self.show(StatusLevel.INFO, f"{pending.request.summary}: {said}")

    def _service(self, asked: NavRequest) -> str:
        return "odometry" if asked.relative is not None else "navigation service"

    def _tell(self, call: NavCall, level: StatusLevel, sentence: str) -> None:
        """To the client: the failure of its service call, or a status for what it published; and on /log."""
        if call.answer is not None:
            self.clients.answer(call.answer, None, sentence)
        elif call.client is not None:
            self.clients.status(call.client, level, sentence)
        self.show(level, sentence)

    def _refused(self, call: NavCall, sentence: str) -> None:
        """The service's own refusal: the service reports it; the view tells the client and shows it."""
        self._tell(call, StatusLevel.WARNING, sentence)

    def _unanswered(self, call: NavCall, why: str, now: float) -> None:
        which = "odometry" if call.request.relative is not None else "nav"
        sentence = f"{why}: is blackmetal {which} running on prefix {self.keys.prefix!r}? The {call.request.summary} went nowhere"
        self._tell(call, StatusLevel.ERROR, sentence)
        who = "a client that left" if call.client is None else f"client {call.client}"
        self.reporter.report(f"foxglove:{call.topic}", f"{who}: {sentence}", now=now)

    def client_gone(self, client: int) -> None:
        for pending in self.calls.values():
            if pending.client == client:
                pending.client = None

    def tick(self, now: float) -> None:
        for call, pending in list(self.calls.items()):
            if now >= pending.deadline:
                del self.calls[call]
                service = self._service(pending.request)
                self._unanswered(pending, f"the {service} did not answer within {self.call_timeout:g} s on {pending.request.key}", now)

    def next_deadline(self) -> float:
        return min((pending.deadline for pending in self.calls.values()), default=math.inf)
