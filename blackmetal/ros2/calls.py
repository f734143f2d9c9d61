"""The node's services answered: ``set_estop``, ``reset_odometry`` and rclcpp's six parameter services. Pure.

Each call waits as a :class:`PendingCall` for its confirmation and is answered once: ``success=false`` with the
reason when refused or at its deadline (docs/ros2-adapter.md "Topics and services").
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal, TypeVar

import msgspec

from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import EStop, GatewayHealth, GatewayParams, Keys, ParamsSet, ParamsSetReply, PayloadError, Pose, decode, encode

from .diagnostics import AdapterStats
from .messages import RosCodec
from .naming import PARAMETER_EVENTS, PARAMETER_SERVICES, RESET_ODOMETRY, SET_ESTOP, attachment, parse_attachment, services
from .options import Ros2Options, Ros2Output
from .parameters import NodeParameters
from .ros_types import RosValue, excerpt

T = TypeVar("T", bound=msgspec.Struct)

#: A pending set_estop puts the e-stop again and asks the gateway's health this often (s), as ``blackmetal estop`` does.
ESTOP_REPEAT_S = 0.1
#: Calls waiting for their confirmation at once; one more is answered success=false at once.
MAX_PENDING_CALLS = 16
#: A reset is confirmed by the odometry answering a pose this close to the origin (m, rad).
RESET_TOLERANCE = 1e-9


@dataclass(slots=True)
class PendingCall:
    """One service call waiting for the gateway's or the odometry's confirmation."""

    call: int
    service: str
    #: (sequence number, client GID) of an rmw_zenoh request, echoed in the reply's attachment; None: none came.
    reply_to: tuple[int, bytes] | None
    deadline: float
    engage: bool = False  # set_estop: the asked state
    repeat_at: float = math.inf  # set_estop: when to put again and ask the health again
    health: GatewayHealth | None = None  # set_estop: the latest health seen while waiting
    #: set_parameters(_atomically): the call's (name, value) pairs and the refusals decided before the gateway answers.
    parameters: list[tuple[str, RosValue]] = field(default_factory=list)
    refused: dict[int, str] = field(default_factory=dict)
    #: A parameter call that came before the gateway's table: its request, run once the table arrives.
    request: bytes | None = None


SERVICE_TYPES = {service.name: service.ros_type for service in services()}
SET_CALLS = ("set_parameters", "set_parameters_atomically")


#: What a query of the core asks, so its replies go where they belong.
ASK_HEALTH, ASK_RESET, ASK_PARAMS, ASK_PARAMS_SET = "health", "reset", "params", "params_set"


def decoded(reporter: ErrorReporter, kind: type[T], payload: bytes, key: str, now: float) -> T | None:
    """``payload`` as a ``kind``; None, reported on ``key`` with the reason, if it is not one."""
    try:
        return decode(kind, payload)
    except PayloadError as exc:
        reporter.report(key, str(exc), exc.excerpt, now=now)
        return None


@dataclass
class ServiceCalls:
    """The calls waiting for their answer, and the queries that will answer them; see the module docstring."""

    options: Ros2Options
    keys: Keys
    output: Ros2Output
    codec: RosCodec
    wallclock: Callable[[], float]
    reporter: ErrorReporter
    stats: AdapterStats
    #: The core's: follow the robot's streams the node needs now (a set_estop waiting needs the health).
    follow: Callable[[], None]
    #: The core's: report and count a bad ROS input.
    reject: Callable[[str, str, str, float], None]
    parameters: NodeParameters = field(default_factory=NodeParameters)
    pending: dict[int, PendingCall] = field(default_factory=dict)
    #: query tag -> (what it asks, the call it serves)
    queries: dict[int, tuple[str, int | None]] = field(default_factory=dict)
    _next_tag: int = 0

    @property
    def waits_for_health(self) -> bool:
        return any(pending.service == SET_ESTOP for pending in self.pending.values())

    def on_health(self, health: GatewayHealth, now: float) -> None:
        for pending in list(self.pending.values()):
            if pending.service == SET_ESTOP:
                pending.health = health
                if health.estop == pending.engage:
                    state = "engaged" if pending.engage else "released"
                    self._finish(pending, True, f"e-stop {state} (confirmed by the gateway's health on {self.keys.health})", now)

    def on_service_request(self, service: str, call: int, cdr: bytes, request_attachment: bytes | None, now: float) -> None:
        key = self.options.service_keys.get(service, service)
        if service not in SERVICE_TYPES:
            return self.output.service_refuse(call, f"no service {service!r} here")
        reply_to = self.reply_to(service, call, request_attachment, now)
        if reply_to is False:
            return None
        pending = PendingCall(call, service, reply_to, deadline=now + self.options.service_timeout)
        if service in PARAMETER_SERVICES:
            if len(self.pending) >= MAX_PENDING_CALLS and (service in SET_CALLS or not self.parameters.known):
                return self._refuse(call, f"{MAX_PENDING_CALLS} calls are already waiting for their answer; call again", now)
            return self._run_parameter_call(pending, cdr, now)
        try:
            request = self.codec.request(SERVICE_TYPES[service], cdr)  # SetBool or Trigger
        except PayloadError as exc:
            self.reject(key, str(exc), exc.excerpt, now)
            return self._finish(pending, False, f"invalid request: {exc}", now)
        pending.engage = service == SET_ESTOP and bool(request.data)
        if len(self.pending) >= MAX_PENDING_CALLS:
            return self._finish(pending, False, f"{MAX_PENDING_CALLS} calls are already waiting for their confirmation; call again", now)
        self.pending[call] = pending
        if service == SET_ESTOP:
            self.follow()
            for other in list(self.pending.values()):  # an older call asking the opposite must stop putting it
                if other.service == SET_ESTOP and other.engage != pending.engage:
                    state = "on" if pending.engage else "off"
                    self._finish(other, False, f"superseded: set_estop {state} was called since", now)
            self._put_estop(pending, now)
        else:
            self._ask(ASK_RESET, self.keys.odometry_reset, None, call, self.options.service_timeout)

    def reply_to(self, service: str, call: int, request_attachment: bytes | None, now: float) -> tuple[int, bytes] | Literal[False] | None:
        """(sequence number, client GID) of an rmw_zenoh request's attachment, None without one; False: refused (reported)."""
        if request_attachment is None:
            return None
        try:
            sequence, _, gid = parse_attachment(request_attachment)
            if sequence < 0:
                raise ValueError(f"sequence number {sequence} is negative")
        except ValueError as exc:
            reason = f"service request with an attachment that is not rmw_zenoh's: {exc}"
            self.reject(self.options.service_keys.get(service, service), reason, excerpt(request_attachment), now)
            self._refuse(call, reason, now)
            return False
        return sequence, gid

    def _put_estop(self, pending: PendingCall, now: float) -> None:
        self.output.blackmetal(self.keys.estop_for(pending.engage), encode(EStop(engaged=pending.engage)))
        self._ask(ASK_HEALTH, self.keys.health, None, None, max(min(pending.deadline - now, 5 * ESTOP_REPEAT_S), ESTOP_REPEAT_S))
        pending.repeat_at = now + ESTOP_REPEAT_S

    def _ask(self, what: str, key: str, payload: bytes | None, call: int | None, timeout: float) -> None:
        self._next_tag += 1
        self.queries[self._next_tag] = (what, call)
        self.output.query(key, payload, self._next_tag, timeout)

    def ask_params(self) -> None:
        self._ask(ASK_PARAMS, self.keys.params, None, None, self.options.service_timeout)

    def on_params(self, payload: bytes, now: float) -> None:
        table = decoded(self.reporter, GatewayParams, payload, self.keys.params, now)
        if table is not None:
            self._take_params(table, now)

    def _take_params(self, table: GatewayParams, now: float) -> None:
        new, changed = self.parameters.on_table(table)
        if new or changed:
            self.output.ros(PARAMETER_EVENTS, self.codec.parameter_event(self.wallclock(), self.options.node, new, changed))
        waiting = [(p, p.request) for p in self.pending.values() if p.request is not None]  # calls that waited for it
        for pending, request in waiting:
            pending.request = None
            del self.pending[pending.call]
            self._run_parameter_call(pending, request, now)

    def _run_parameter_call(self, pending: PendingCall, cdr: bytes, now: float) -> None:
        """Answered from the table now, or (a set) when the gateway has answered; before the table has arrived the call
        waits for it, so ``ros2 param list`` at start-up lists the parameters, not nothing."""
        service, p, codec = pending.service, self.parameters, self.codec
        if not p.known:
            pending.request = cdr
            self.pending[pending.call] = pending
            return self.ask_params()
        ros_type = PARAMETER_SERVICES[service]
        try:
            if service not in SET_CALLS:
                return self._answer(pending, True, codec.parameter_response(ros_type, cdr, p.table), now)
            pending.parameters = codec.set_parameters_request(ros_type, cdr)
        except PayloadError as exc:
            self.reject(self.options.service_keys.get(service, service), str(exc), exc.excerpt, now)
            return self._refuse(pending.call, f"invalid request: {exc}", now)
        values, pending.refused = p.plan(pending.parameters, atomically=service == "set_parameters_atomically")
        for reason in pending.refused.values():
            self.reporter.report(self.options.service_keys.get(service, service), f"{service}: {reason}", "", now=now)
        if not values:
            return self._answer_set(pending, None, now)
        self.pending[pending.call] = pending
        self._ask(ASK_PARAMS_SET, self.keys.params_set, encode(ParamsSet(values=values)), pending.call, self.options.service_timeout)

    def _answer_set(self, pending: PendingCall, reply: ParamsSetReply | None, now: float, failure: str = "") -> None:
        """The SetParametersResult(s) of a set call: the refusals decided here, else the gateway's result for the name."""
        results = {r.name: r for r in reply.results} if reply is not None else {}
        answers: list[tuple[bool, str]] = []
        for i, (name, _) in enumerate(pending.parameters):
            if i in pending.refused:
                answers.append((False, pending.refused[i]))
            elif name in results:
                answers.append((results[name].successful, results[name].reason))
            else:
                answers.append((False, failure or f"the gateway did not answer for {name}"))
        if pending.service == "set_parameters_atomically":
            ok = bool(answers) and all(good for good, _ in answers)
            reasons = "; ".join(dict.fromkeys(reason for good, reason in answers if not good and reason))
            if not ok and any(good for good, _ in answers):
                reasons += " (the gateway set the others: it sets each value on its own)"
            answers = [(ok, reasons)]
        ok = all(good for good, _ in answers)
        self._answer(pending, ok, self.codec.set_parameters_response(PARAMETER_SERVICES[pending.service], answers), now)

    def on_query_reply(self, tag: int, ok: bool, payload: bytes, now: float) -> None:
        what, call = self.queries.get(tag, ("", None))
        if what == ASK_PARAMS:
            if ok:
                self.on_params(payload, now)
            return
        pending = self.pending.get(call) if call is not None else None
        if pending is None:
            return
        setting = what == ASK_PARAMS_SET
        if not ok:
            reason = payload.decode(errors="replace")
            if setting:
                return self._fail(pending, f"the gateway on {self.keys.prefix!r} refused the set: {reason or 'no reason given'}", now)
            return self._fail(pending, f"the odometry refused the reset: {reason}", now)
        try:
            reply = decode(ParamsSetReply if setting else Pose, payload)
        except PayloadError as exc:
            who, kind = ("gateway", "a ParamsSetReply") if setting else ("odometry", "a pose")
            return self._fail(pending, f"the {who} answered something that is not {kind}: {exc}", now)
        if isinstance(reply, ParamsSetReply):
            self._take_params(reply.params, now)
            return self._answer_set(pending, reply, now)
        assert isinstance(reply, Pose)
        if max(abs(reply.x), abs(reply.y), abs(reply.yaw)) <= RESET_TOLERANCE:
            self._finish(pending, True, f"odometry reset to x=0 y=0 yaw=0 (confirmed by the odometry on {self.keys.odometry_reset})", now)
        else:
            self._fail(pending, f"the odometry answered x={reply.x:g} y={reply.y:g} yaw={reply.yaw:g} after the reset", now)

    def on_query_done(self, tag: int, now: float) -> None:
        """No more replies to ``tag`` will come: a reset or a parameter set nobody answered fails now."""
        what, call = self.queries.pop(tag, (ASK_HEALTH, None))
        pending = self.pending.get(call) if call is not None else None
        if pending is not None:
            who, key, nothing = (
                ("gateway", self.keys.params_set, ": nothing was set")
                if what == ASK_PARAMS_SET
                else ("odometry", self.keys.odometry_reset, "")
            )
            self._fail(pending, f"no {who} answered on {key} (is it running on prefix {self.keys.prefix}?){nothing}", now)

    def _fail(self, pending: PendingCall, reason: str, now: float) -> None:
        if pending.service in SET_CALLS:
            self._answer_set(pending, None, now, reason)
        else:
            self._finish(pending, False, reason, now)

    def _finish(self, pending: PendingCall, success: bool, message: str, now: float) -> None:
        self._answer(pending, success, self.codec.response(SERVICE_TYPES[pending.service], success=success, message=message), now)

    def _answer(self, pending: PendingCall, success: bool, cdr: bytes, now: float) -> None:
        self.pending.pop(pending.call, None)
        if pending.service == SET_ESTOP:
            self.follow()  # the health is followed no longer, unless /diagnostics needs it
        if success:
            self.stats.confirmed += 1
        else:
            self.stats.failed.add(now)
        reply_attachment = None
        if pending.reply_to is not None:
            sequence, gid = pending.reply_to
            reply_attachment = attachment(sequence, round(self.wallclock() * 1e9), gid)
        self.output.service_reply(pending.call, cdr, reply_attachment)

    def _refuse(self, call: int, reason: str, now: float) -> None:
        """Answer ``call`` with a Zenoh error reply (there is no request to answer a response to), counted as failed."""
        self.stats.failed.add(now)
        self.output.service_refuse(call, reason)

    def _timed_out(self, pending: PendingCall, now: float) -> None:
        limit = f"{self.options.service_timeout:g} s"
        if pending.request is not None:  # it waited for the gateway's table, which never came
            self.pending.pop(pending.call, None)
            where = f"({self.keys.params}): is it running on prefix {self.keys.prefix}?"
            return self._refuse(pending.call, f"the gateway's parameters did not arrive within {limit} {where}", now)
        if pending.service in SET_CALLS:
            return self._fail(pending, f"the gateway did not answer within {limit} ({self.keys.params_set}); nothing known set", now)
        if pending.service == RESET_ODOMETRY:
            return self._fail(pending, f"the odometry did not answer the reset within {limit} ({self.keys.odometry_reset})", now)
        state = "on" if pending.engage else "off"
        if pending.health is None:
            seen = f"no health on {self.keys.health}: is the gateway running on prefix {self.keys.prefix}?"
        else:
            seen = f"its health still says estop={str(pending.health.estop).lower()}"
        self._fail(pending, f"the gateway did not confirm the e-stop {state} within {limit} ({seen})", now)

    def tick(self, now: float) -> None:
        for pending in list(self.pending.values()):
            if now >= pending.deadline:
                self._timed_out(pending, now)
            elif now >= pending.repeat_at:
                self._put_estop(pending, now)

    def next_deadline(self) -> float:
        return min((min(p.deadline, p.repeat_at) for p in self.pending.values()), default=math.inf)
