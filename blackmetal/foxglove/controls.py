"""What the view's clients may publish and call, turned into the robot's keys (docs/foxglove.md, "Controls").

Pure and clock-injected like every core. A refusal is a status to that client and a report on ``<prefix>/errors``;
a fleet's :class:`FleetControls` feed each robot's :class:`Controls` only what names it.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import msgspec

from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import ErrorReport, EStop, GatewayHealth, Keys, PayloadError, Pose, PoseReset, Twist, decode, encode, excerpt

from .goals import Header, NavDesk, robot_of_frame
from .naming import (
    CLIENT_ENCODING,
    COMMAND_SOURCE,
    CONTROL_SCHEMAS,
    NAV_SCHEMAS,
    Control,
    NavTopic,
    ServerRefusal,
    Service,
    StatusLevel,
    control_topic,
    nav_takes,
    nav_topic,
    robot_frame,
    robot_namespace,
    robot_of,
    service_name,
    takes,
)
from .params import Clients
from .zenoh_edge import NO_EDGE, FoxgloveZenoh, NoEdge

#: A set_estop call re-sends its engage and asks the gateway's health this often (s) until confirmed.
ASK_PERIOD_S = 0.2
#: A refused client channel gets at most one status message this often (s); every refusal is still counted in reports.
STATUS_PERIOD_S = 1.0
RELEASE_HINT = 'only {"data": false} releases the e-stop'


class RosBool(msgspec.Struct, forbid_unknown_fields=True):
    """std_msgs/msg/Bool and the std_srvs/srv/SetBool request, as JSON: ``{"data": true}``."""

    data: bool


@dataclass(slots=True)
class ClientTopic:
    """A channel a client advertised: what it controls, or why its messages are refused."""

    topic: str
    control: Control | None
    refusal: str | None
    drove: bool = False
    #: The 3D panel's topic it is (a goal, a pose estimate, a point), None for another.
    nav: NavTopic | None = None


@dataclass(slots=True)
class PendingCall:
    """A service call waiting for its confirmation; ``engage`` and ``next_ask``: a set_estop's."""

    client: int
    deadline: float
    engage: bool = False
    next_ask: float = math.inf


def _mistyped(topic: str, encoding: str, schema_name: str, schemas: tuple[str, ...]) -> str | None:
    """Why a client channel on a topic the view takes is refused (its encoding or schema), None when it is not."""
    if encoding != CLIENT_ENCODING:
        return f"{topic} must be {CLIENT_ENCODING}-encoded, not {encoding!r}"
    if schema_name and schema_name not in schemas:
        return f"{topic} carries {' or '.join(schemas)}, not {schema_name!r}"
    return None


class _Framed(msgspec.Struct):
    """Just the header of a stamped message: which robot's frame a fleet's bare /goal_pose names."""

    header: Header = msgspec.field(default_factory=Header)


def _state(engage: bool) -> str:
    return "engaged" if engage else "released"


class Refusals:
    """What :class:`Controls` and :class:`FleetControls` both do with what they refuse: tell the client, and report it."""

    def __init__(self, clients: Clients, report: Callable[[ErrorReport], None], wallclock: Callable[[], float]) -> None:
        self.reporter = ErrorReporter("foxglove", report, wallclock)
        self.clients = clients
        self._last_status: dict[tuple[int | None, str], float] = {}

    def _refuse(self, client: int | None, topic: str, reason: str, text: str, now: float) -> None:
        last = self._last_status.get((client, topic), -math.inf)
        if now - last >= STATUS_PERIOD_S:
            self._last_status[(client, topic)] = now
            self.clients.status(client, StatusLevel.ERROR, f"blackmetal refused a message on {topic}: {reason}")
        self.reporter.report(f"foxglove:{topic}", f"client {client}: {reason}", text, now=now)

    def _unknown_service(self, call: int, client: int, service: str, offered: str, payload: bytes, now: float) -> None:
        self.clients.answer(call, None, f"unknown service {service!r}: this view offers {offered}")
        self.reporter.report(f"foxglove:{service}", f"client {client}: unknown service", excerpt(payload), now=now)

    def _forget(self, client: int) -> None:
        for status_key in [key for key in self._last_status if key[0] == client]:
            del self._last_status[status_key]

    def on_server_refusal(self, client: int | None, kind: ServerRefusal, message: str, now: float) -> None:
        """The WebSocket server refused a client's message itself (bad JSON, unknown channel...): report it."""
        if kind is ServerRefusal.SERVICE_CALL_FAILURE:
            self.clients.status(client, StatusLevel.ERROR, f"blackmetal refused a service call: {message}")
        self.reporter.report("foxglove:client", f"client {client}: {message}", now=now)


class Controls(Refusals):
    """Client publications and service calls -> the robot's keys, with confirmations and refusals; ``call``: the host's
    number of a service call."""

    def __init__(
        self,
        keys: Keys,
        clients: Clients,
        call_timeout: float = 2.0,
        wallclock: Callable[[], float] = time.time,
        namespace: str = "",
        robot: FoxgloveZenoh | NoEdge = NO_EDGE,
    ) -> None:
        super().__init__(clients, lambda message: self.robot.error(message), wallclock)
        #: The robot's edge while the session is open; it may change (the view plugs it in and out).
        self.robot = robot
        self.keys = keys
        #: ``""``, or ``/<id>`` for a fleet's robot: it takes ``/<id>/cmd_vel``, ``/<id>/estop``, ``/<id>/set_estop``, ...
        self.namespace = namespace
        self._controls = {control_topic(namespace, c): c for c in Control}
        self._nav_topics = {nav_topic(namespace, t): t for t in NavTopic}
        robot_id = namespace.removeprefix("/")
        self.nav = NavDesk(
            keys,
            clients,
            self.reporter,
            self._refuse,
            lambda key, call, payload: self.robot.ask_nav(key, call, payload),
            call_timeout,
            robot_frame(robot_id, "") if robot_id else "",
        )
        self._services = {service_name(namespace, s): s for s in Service}
        self.call_timeout = call_timeout
        self.cmd_vel_key = keys.cmd_vel_of(COMMAND_SOURCE)
        self._topics: dict[tuple[int, int], ClientTopic] = {}
        self._estop_calls: dict[int, PendingCall] = {}
        self._reset_calls: dict[int, PendingCall] = {}
        #: The e-stop state in the gateway's last health (None: no health seen yet).
        self.estop_seen: bool | None = None

    def on_advertise(self, client: int, channel: int, topic: str, encoding: str, schema_name: str, now: float) -> None:
        control, nav = self._controls.get(topic), self._nav_topics.get(topic)
        schemas = CONTROL_SCHEMAS[control] if control is not None else NAV_SCHEMAS[nav] if nav is not None else ()
        if control is None and nav is None:
            refusal: str | None = f"topic {topic!r} is not taken here: clients publish {takes(self.namespace)}; {nav_takes(self.namespace)}"
        else:
            refusal = _mistyped(topic, encoding, schema_name, schemas)
        self._topics[(client, channel)] = ClientTopic(topic, control, refusal, nav=nav)
        if refusal is not None:
            self._refuse(client, topic, f"{refusal}; its messages are refused", "", now)

    def on_unadvertise(self, client: int, channel: int, now: float) -> None:
        """A /cmd_vel that drove sends one zero command, so the robot stops now rather than at the timeout."""
        topic = self._topics.pop((client, channel), None)
        if topic is not None and topic.control is Control.CMD_VEL and topic.drove:
            self.robot.command(self.cmd_vel_key, encode(Twist()))

    def on_client_gone(self, client: int, now: float) -> None:
        for key in [key for key in self._topics if key[0] == client]:
            self.on_unadvertise(client, key[1], now)
        self._forget(client)
        self.nav.client_gone(client)

    def on_message(self, client: int, channel: int, data: bytes, now: float) -> None:
        topic = self._topics.get((client, channel))
        if topic is None:
            return self._refuse(client, f"channel {channel}", f"channel {channel} was not advertised by this client", excerpt(data), now)
        if topic.refusal is not None:
            return self._refuse(client, topic.topic, topic.refusal, excerpt(data), now)
        if topic.nav is not None:
            return self.nav.on_message(client, topic.topic, topic.nav, data, now)
        if topic.control is Control.CMD_VEL:
            try:
                twist = decode(Twist, data)
            except PayloadError as exc:
                return self._refuse(client, topic.topic, f"{exc}; nothing was sent to the robot", exc.excerpt, now)
            topic.drove = True
            self.robot.command(self.cmd_vel_key, encode(twist))
        elif topic.control is Control.ESTOP:
            try:
                wish = decode(RosBool, data)
            except PayloadError as exc:
                self._estop(True, now)  # fails safe, as the gateway does: whoever published here meant the stop
                return self._refuse(client, topic.topic, f"{exc}: the e-stop is engaged; {RELEASE_HINT}", exc.excerpt, now)
            self._estop(wish.data, now)

    def _estop(self, engage: bool, now: float, call: int | None = None) -> None:
        """Put the e-stop; a pending set_estop call that wants the other state is superseded (its re-sends would undo this)."""
        self.robot.command(self.keys.estop_for(engage), encode(EStop(engaged=engage)))
        for other, pending in list(self._estop_calls.items()):
            if other != call and pending.engage != engage:
                self._fail(
                    other, pending.client, Service.SET_ESTOP, f"superseded: the e-stop was {_state(engage)} since this call", "", now
                )

    def on_service_call(self, call: int, client: int, service: str, payload: bytes, now: float) -> None:
        known = self._services.get(service)
        if known is Service.SET_ESTOP:
            try:
                wish = decode(RosBool, payload)
            except PayloadError as exc:
                self._estop(True, now)
                return self._fail(call, client, known, f"{exc}: the e-stop is engaged; {RELEASE_HINT}", exc.excerpt, now)
            self._estop_calls[call] = PendingCall(client, now + self.call_timeout, wish.data, now + ASK_PERIOD_S)
            self._estop(wish.data, now, call)
            self.robot.ask_health()  # asked after the put: the gateway takes its e-stop samples first
        elif known is Service.RESET_ODOMETRY:
            try:
                target = PoseReset() if not payload.strip() else decode(PoseReset, payload)
            except PayloadError as exc:
                return self._fail(call, client, known, f"{exc}; the odometry was not reset", exc.excerpt, now)
            self._reset_calls[call] = PendingCall(client, now + self.call_timeout)
            self.robot.ask_reset(call, encode(target))
        elif known is Service.CANCEL_GOAL:
            self.nav.cancel(call, client, service, now)  # std_srvs/Trigger: its request carries nothing to read
        else:
            self._unknown_service(call, client, service, ", ".join(self._services), payload, now)

    def on_health(self, payload: bytes, now: float) -> None:
        try:
            health = decode(GatewayHealth, payload)
        except PayloadError:
            return  # the gateway's own key: the view shows what it can, the gateway reports its own
        self.estop_seen = health.estop
        message = f"e-stop {_state(health.estop)} (confirmed by the gateway's health)"
        for call in [call for call, pending in self._estop_calls.items() if pending.engage == health.estop]:
            del self._estop_calls[call]
            self.clients.answer(call, json.dumps({"success": True, "message": message}).encode(), None)

    def on_reset_reply(self, call: int, ok: bytes | None, err: bytes | None, now: float) -> None:
        """``None, None``: the query ended unanswered."""
        pending = self._reset_calls.pop(call, None)
        if pending is None:
            return
        reason, text = "", ""
        if ok is None and err is None:
            reason = f"no odometry answered on {self.keys.odometry_reset}: is blackmetal odometry running on prefix {self.keys.prefix!r}?"
        elif ok is None:
            reason = f"the odometry refused the reset: {(err or b'').decode('utf-8', errors='replace') or 'no reason given'}"
        else:
            try:
                pose = decode(Pose, ok)
            except PayloadError as exc:
                reason, text = f"the odometry answered something else than a pose: {exc}", exc.excerpt
        if reason:
            return self._fail(call, pending.client, Service.RESET_ODOMETRY, reason, text, now)
        message = f"odometry reset to x={pose.x:g} y={pose.y:g} yaw={pose.yaw:g} (confirmed by the odometry)"
        self.clients.answer(call, msgspec.json.encode({"success": True, "message": message, "pose": pose}), None)

    def on_nav_reply(self, call: int, ok: bytes | None, err: bytes | None, now: float) -> None:
        self.nav.on_reply(call, ok, err, now)

    def _fail(self, call: int, client: int, service: Service, reason: str, text: str, now: float) -> None:
        self._estop_calls.pop(call, None)
        self._reset_calls.pop(call, None)
        self.clients.answer(call, None, reason)
        self.reporter.report(f"foxglove:{service_name(self.namespace, service)}", f"client {client}: {reason}", text, now=now)

    def tick(self, now: float) -> None:
        for call, pending in list(self._estop_calls.items()):
            if now >= pending.deadline:
                seen = (
                    "no health from the gateway" if self.estop_seen is None else f"its health says the e-stop is {_state(self.estop_seen)}"
                )
                reason = (
                    f"the gateway did not confirm the e-stop {_state(pending.engage)} within {self.call_timeout:g} s ({seen}); "
                    f"is blackmetal gateway running on prefix {self.keys.prefix!r}?"
                )
                self._fail(call, pending.client, Service.SET_ESTOP, reason, "", now)
            elif now >= pending.next_ask:
                pending.next_ask = now + ASK_PERIOD_S
                if pending.engage:  # an engage is safe to repeat; a release is sent once, never over someone's later stop
                    self.robot.command(self.keys.estop, encode(EStop(engaged=True)))
                self.robot.ask_health()
        for call, reset in list(self._reset_calls.items()):
            if now >= reset.deadline:
                reason = f"the odometry did not answer within {self.call_timeout:g} s on {self.keys.odometry_reset}"
                self._fail(call, reset.client, Service.RESET_ODOMETRY, reason, "", now)
        self.nav.tick(now)
        self.reporter.tick(now)

    def next_deadline(self) -> float:
        pending = [*self._estop_calls.values(), *self._reset_calls.values()]
        return min([self.reporter.next_deadline(), self.nav.next_deadline(), *(min(p.deadline, p.next_ask) for p in pending)])


class FleetControls(Refusals):
    """One :class:`Controls` per robot (namespace ``/<id>``), each fed only what names its robot; the rest is refused here
    and reported on ``fleet_error`` (the fleet's log), never on a robot's key."""

    def __init__(
        self,
        robots: dict[str, Controls],
        clients: Clients,
        fleet_error: Callable[[ErrorReport], None],
        wallclock: Callable[[], float] = time.time,
    ) -> None:
        super().__init__(clients, fleet_error, wallclock)
        self.robots = robots
        self._takes = f"{takes('/<id>')} for the robots {', '.join(robots)}; {nav_takes('/<id>')}"
        #: (client, channel) -> the robot it names, or None with the topic it refused.
        self._channels: dict[tuple[int, int], tuple[str | None, str]] = {}
        #: The 3D panel's bare topics (/goal_pose...): each message goes to the robot its frame names (r3/odom: r3).
        self._bare_nav = {t.value: t for t in NavTopic}
        self._nav_channels: dict[tuple[int, int], tuple[str, NavTopic, str | None]] = {}

    def on_advertise(self, client: int, channel: int, topic: str, encoding: str, schema_name: str, now: float) -> None:
        robot_id = robot_of(topic, self.robots)
        nav = self._bare_nav.get(topic)
        if robot_id is None and nav is not None:
            refusal = _mistyped(topic, encoding, schema_name, NAV_SCHEMAS[nav])
            self._nav_channels[(client, channel)] = (topic, nav, refusal)
            if refusal is not None:
                self._refuse(client, topic, f"{refusal}; its messages are refused", "", now)
            return
        self._channels[(client, channel)] = (robot_id, topic)
        if robot_id is not None:
            self.robots[robot_id].on_advertise(client, channel, topic, encoding, schema_name, now)
        else:
            self._refuse(client, topic, f"{self._not_taken(topic)}; its messages are refused", "", now)

    def _not_taken(self, topic: str) -> str:
        return f"topic {topic!r} is not taken here: clients publish {self._takes}"

    def on_unadvertise(self, client: int, channel: int, now: float) -> None:
        self._nav_channels.pop((client, channel), None)
        robot_id, _ = self._channels.pop((client, channel), (None, ""))
        if robot_id is not None:
            self.robots[robot_id].on_unadvertise(client, channel, now)

    def on_client_gone(self, client: int, now: float) -> None:
        for key in [key for key in [*self._channels, *self._nav_channels] if key[0] == client]:
            self.on_unadvertise(client, key[1], now)
        self._forget(client)
        for controls in self.robots.values():
            controls.on_client_gone(client, now)

    def _nav_message(self, client: int, topic: str, nav: NavTopic, data: bytes, now: float) -> None:
        """A bare /goal_pose (or pose estimate, point): to the robot whose frame it is in."""
        try:
            frame = msgspec.json.decode(data, type=_Framed).header.frame_id
        except (msgspec.DecodeError, msgspec.ValidationError) as exc:
            return self._refuse(client, topic, f"not a stamped message ({exc}); nothing was sent to any robot", excerpt(data), now)
        robot_id = robot_of_frame(frame, self.robots)
        if robot_id is None:
            reason = (
                f"in a fleet a pose on {topic} names its robot by its frame (r2/odom: r2), and {frame!r} names none of "
                f"{', '.join(self.robots)}; "
                f"publish on {nav_topic('/<id>', nav)} or set the 3D panel's frame to <id>/odom; nothing was sent to any robot"
            )
            return self._refuse(client, topic, reason, excerpt(data), now)
        self.robots[robot_id].nav.on_message(client, topic, nav, data, now)

    def on_message(self, client: int, channel: int, data: bytes, now: float) -> None:
        bare = self._nav_channels.get((client, channel))
        if bare is not None:
            topic, nav, refusal = bare
            if refusal is not None:
                return self._refuse(client, topic, refusal, excerpt(data), now)
            return self._nav_message(client, topic, nav, data, now)
        known = self._channels.get((client, channel))
        if known is None:
            self._refuse(client, f"channel {channel}", f"channel {channel} was not advertised by this client", excerpt(data), now)
        elif known[0] is None:
            self._refuse(client, known[1], self._not_taken(known[1]), excerpt(data), now)
        else:
            self.robots[known[0]].on_message(client, channel, data, now)

    def on_service_call(self, call: int, client: int, service: str, payload: bytes, now: float) -> None:
        robot_id = robot_of(service, self.robots)
        if robot_id is not None:
            return self.robots[robot_id].on_service_call(call, client, service, payload, now)
        offered = ", ".join(service_name(robot_namespace("<id>"), s) for s in Service)
        self._unknown_service(call, client, service, f"{offered} for the robots {', '.join(self.robots)}", payload, now)

    def tick(self, now: float) -> None:
        for controls in self.robots.values():
            controls.tick(now)
        self.reporter.tick(now)

    def next_deadline(self) -> float:
        return min([self.reporter.next_deadline(), *(c.next_deadline() for c in self.robots.values())])
