"""The gateway's side of the robot, sans I/O (as h11 is for HTTP): bytes, commands and ``now`` in; bytes, messages and a deadline out.

Everything the gateway decides lives here, in one pure object with no
sockets, no Zenoh and no clock of its own:

* after the control link comes up: PREPARE_WHEEL_CONTROLLER, then zero
  velocity (the robot never resumes an old motion);
* velocity commands from ``cmd_vel`` through the safety governor (limits,
  command timeout, e-stop latch with EMG_STOP ahead of everything,
  coalescing of floods, keep-alive before the robot's 10 s watchdog);
* polling at a fixed rate, never more than one poll outstanding;
* pairing replies with requests (:mod:`gateway.exchange`), FULL_BUFFER
  retries, requests given up after the reply timeout;
* a silent control link or log link is dropped so the host reconnects;
* impulses, status, health and error reports as schema messages.

The host (:mod:`gateway.service`) feeds it with :meth:`link_up`,
:meth:`link_down`, :meth:`receive`, :meth:`on_cmd_vel`, :meth:`on_estop` and
:meth:`tick`, then writes :meth:`take_outgoing` to each link, acts on
:meth:`take_events`, and sleeps until :meth:`next_deadline`. Tests drive it
with a fake clock and no I/O at all.
"""

from __future__ import annotations

import math
import secrets
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from blackmetal import wire
from blackmetal.robot_model import NOMINAL_ENCODERS, WheelSpeeds
from blackmetal.runtime.reports import ErrorReporter
from blackmetal.wire import CommandCode, LogReport, Malformed, ReplyDecoder
from schemas import (
    ErrorReport,
    GatewayHealth,
    Keys,
    LinkHealth,
    PayloadError,
    RobotStatus,
    Twist,
    WheelImpulses,
    decode,
    excerpt,
)

from .estop import read_estop
from .exchange import Completed, Exchange, Lost
from .safety import Governor, retry_delay
from .settings import GatewaySettings

#: Requests in flight (late ones included) beyond which only stops go out, and polls wait.
MAX_IN_FLIGHT = 8
#: A conflict with another gateway on the prefix holds this long after its last health report (s).
CONFLICT_HOLD_S = 3.0

LinkName = Literal["control", "log"]
LINKS: tuple[LinkName, LinkName] = ("control", "log")


@dataclass(frozen=True, slots=True)
class DropLink:
    """The host must close this link (it reconnects by itself)."""

    link: LinkName
    reason: str


Event = WheelImpulses | RobotStatus | GatewayHealth | ErrorReport | DropLink


@dataclass
class Counters:
    commands_sent: int = 0
    polls: int = 0
    polls_skipped: int = 0
    replies: int = 0
    full_buffer: int = 0
    full_buffer_retries: int = 0
    lost_replies: int = 0
    malformed_replies: int = 0
    rejected_inputs: int = 0
    keepalives: int = 0


@dataclass
class LinkState:
    """What the connection knows of one link: up or not, since when, how often."""

    state: str = "down"  # "down", "connecting" or "connected"
    connected_since: float | None = None  # Unix time
    connections: int = 0
    last_rx: float = 0.0
    waiting_since: float | None = None  # first request sent since the last bytes received

    @property
    def connected(self) -> bool:
        return self.state == "connected"

    @property
    def reconnects(self) -> int:
        return max(0, self.connections - 1)

    def health(self) -> LinkHealth:
        return LinkHealth(self.state, self.connected_since, self.reconnects)


class ReconnectBackoff:
    """How long to wait before the next connection attempt: doubling, capped, reset only by a stable connection.

    A connection that the robot closes within ``stable`` seconds of opening
    counts as a failure, so a robot that accepts and at once closes or resets
    gets attempts at the capped pace, not a storm.
    """

    def __init__(self, first: float = 0.05, cap: float = 2.0, stable: float = 5.0) -> None:
        self.first = first
        self.cap = cap
        self.stable = stable
        self.delay = first
        self._opened_at: float | None = None

    def opened(self, now: float) -> None:
        self._opened_at = now

    def failed(self, now: float) -> float:
        """A connection attempt failed, or a connection ended: the pause before the next attempt."""
        if self._opened_at is not None and now - self._opened_at >= self.stable:
            self.delay = self.first  # that connection was a good one: start over
        wait = self.delay
        self.delay = min(self.cap, self.delay * 2)
        self._opened_at = None
        return wait


def _is_stop(request: wire.Request) -> bool:
    if request.command in (CommandCode.EMG_STOP, CommandCode.NORMAL_STOP):
        return True
    return request.command is CommandCode.SET_LR_WHEEL_VELOCITY and request.right == 0.0 and request.left == 0.0


def _wheels(request: wire.Request) -> WheelSpeeds:
    return WheelSpeeds(float(request.right or 0.0), float(request.left or 0.0))


class RobotConnection:
    """See the module docstring. ``robot`` names the robot's control and log ends in reports."""

    def __init__(
        self,
        settings: GatewaySettings,
        now: float,
        wallclock: Callable[[], float],
        robot: dict[str, str] | None = None,
        source: str | None = None,
    ) -> None:
        self.settings = settings
        self.wallclock = wallclock
        self.keys = Keys(settings.prefix)
        self.counters = Counters()
        self.governor = Governor(settings.safety(), now)
        self.exchange = Exchange(reply_timeout=settings.reply_timeout, late_horizon=3 * settings.reply_timeout)
        self.links: dict[LinkName, LinkState] = {name: LinkState() for name in LINKS}
        self.last_rtt: float | None = None
        self.seq = 0
        #: Names this run of the gateway in every impulse sample, so the odometry can tell a restart from a replay.
        self.source = source or secrets.token_hex(6)
        self._now = now
        self._robot = robot or {"control": "robot:control", "log": "robot:log"}
        self._decoders: dict[LinkName, ReplyDecoder] = {name: ReplyDecoder() for name in LINKS}
        self._outgoing: dict[LinkName, bytearray] = {name: bytearray() for name in LINKS}
        self._events: list[Event] = []
        self.reporter = ErrorReporter("gateway", self._events.append, clock=lambda: self._now, wallclock=wallclock)
        self._period = 1.0 / settings.poll_hz
        self._next_poll = math.inf
        self._next_health = now
        self._last_status: RobotStatus | None = None
        self._last_status_at = -math.inf
        self._poll_times: deque[float] = deque(maxlen=4096)
        self._prepare_at: float | None = None  # PREPARE to re-send (after FULL_BUFFER) at this time
        self._prepare_attempts = 0
        self._down_since: dict[LinkName, float | None] = {name: None for name in LINKS}
        self._health_now = False
        #: Another gateway seen on this prefix: its run id, and until when the conflict holds without news of it.
        self.conflict_with: str | None = None
        self._conflict_until = -math.inf
        self._conflict_reported = -math.inf
        self.stopping = False

    # ------------------------------------------------------------------ outputs

    def take_outgoing(self, link: LinkName) -> bytes:
        """Bytes to write to ``link`` now (each request complete, in order)."""
        data = self._outgoing[link]
        if not data:
            return b""
        out = bytes(data)
        data.clear()
        return out

    def take_events(self) -> list[Event]:
        """Messages to publish and links to drop, in the order they arose (take the outgoing bytes first)."""
        if self._health_now:
            self._health_now = False
            self._events.append(self.health(self._now))
        events, self._events[:] = list(self._events), []
        return events

    def next_deadline(self) -> float:
        """When :meth:`tick` must run next, at the latest (monotonic seconds)."""
        deadline = min(self._next_health, self.exchange.next_expiry(), self.governor.next_deadline(self._congested()))
        if self.conflict_with is not None:
            deadline = min(deadline, self._conflict_until, self._conflict_reported + 1.0)
        control, log = self.links["control"], self.links["log"]
        if control.connected:
            deadline = min(deadline, self._next_poll)
            if self._prepare_at is not None:
                deadline = min(deadline, self._prepare_at)
            if control.waiting_since is not None:
                deadline = min(deadline, control.waiting_since + self.settings.silence_timeout)
        if log.connected:
            deadline = min(deadline, log.last_rx + self.settings.log_silence_timeout)
        return deadline

    # ------------------------------------------------------------------ link events

    def link_connecting(self, link: LinkName) -> None:
        self.links[link].state = "connecting"

    def link_up(self, link: LinkName, now: float) -> None:
        """``link`` is connected (again): start clean."""
        self._now = now
        state = self.links[link]
        state.state = "connected"
        state.connected_since = self.wallclock()
        state.connections += 1
        state.last_rx = now
        state.waiting_since = None
        self._decoders[link].reset()
        self._outgoing[link].clear()
        down_since = self._down_since[link]
        if down_since is not None:
            self._down_since[link] = None
            self.reporter.report(self._robot[link], f"{link} link up again after {now - down_since:.1f} s", source="robot")
        if link == "control":
            self.exchange.clear("reconnected")
            self._prepare_at = None
            self._prepare_attempts = 0
            self._send(wire.simple(CommandCode.PREPARE_WHEEL_CONTROLLER), now)
            self.governor.on_link_up(now)
            self._next_poll = now
            self._pump(now)

    def link_down(self, link: LinkName, reason: str, now: float) -> None:
        """``link`` closed, or could not be opened."""
        self._now = now
        state = self.links[link]
        was_up = state.connected
        state.state = "down"
        state.connected_since = None
        state.waiting_since = None
        self._outgoing[link].clear()
        if was_up:
            self._down_since[link] = now
            if not self.stopping:
                self.reporter.report(self._robot[link], f"{link} link down: {reason}", source="robot")
        if link == "control" and was_up:
            self.governor.on_link_down()
            self.counters.lost_replies += len(self.exchange.clear(reason))
            self._next_poll = math.inf
            self._prepare_at = None

    def receive(self, link: LinkName, data: bytes, now: float) -> None:
        """Bytes read from ``link``."""
        self._now = now
        state = self.links[link]
        state.last_rx = now
        state.waiting_since = None
        if link == "control":
            self._receive_control(data, now)
        else:
            self._receive_log(data)

    # ------------------------------------------------------------------ Zenoh inputs

    def on_cmd_vel(self, payload: bytes, now: float) -> None:
        """A payload put on ``<prefix>/cmd_vel``: decoded, checked, sent or reported."""
        self._now = now
        try:
            twist = decode(Twist, payload)
        except PayloadError as exc:
            self.reject(self.keys.cmd_vel, str(exc), exc.excerpt)
            return
        if now < self._conflict_until:
            self.reject(self.keys.cmd_vel, self._conflict_reason(), excerpt(payload))
            return
        reason = self.governor.on_twist(twist, now)
        if reason is not None:
            self.reject(self.keys.cmd_vel, reason, excerpt(payload))
            return
        self._pump(now)

    def on_estop(self, payload: bytes, now: float) -> None:
        """A payload put on ``<prefix>/estop``: anything but a valid release engages (see :mod:`gateway.estop`)."""
        self._now = now
        engaged, complaint = read_estop(payload)
        if complaint is not None:
            self.reject(self.keys.estop, complaint, excerpt(payload))
        self.governor.on_estop(engaged, now)
        self._pump(now)
        self._health_now = True  # reported from take_events, after the host has written the EMG_STOP

    def on_health_seen(self, payload: bytes, now: float) -> None:
        """A health report on our own key: one from another gateway run means two gateways share this prefix."""
        self._now = now
        try:
            other = decode(GatewayHealth, payload).source
        except PayloadError:
            return
        if other is None or other == self.source:
            return
        if now >= self._conflict_until:  # a new conflict: stop driving at once
            self.governor.brake()
            self._conflict_reported = -math.inf
        self.conflict_with = other
        self._conflict_until = now + CONFLICT_HOLD_S
        self._report_conflict(now)
        self._pump(now)

    def _conflict_reason(self) -> str:
        return (
            f"another gateway (run {self.conflict_with}) serves prefix {self.keys.prefix}: both brake and refuse cmd_vel "
            "until one leaves; give one of them another --prefix"
        )

    def _report_conflict(self, now: float) -> None:
        if now >= self._conflict_reported + 1.0:
            self._conflict_reported = now
            self.reporter.report(self.keys.health, self._conflict_reason(), source="gateway")

    def reject(self, key: str, reason: str, snippet: str = "") -> None:
        """An input refused: counted and reported on ``<prefix>/errors``."""
        self.counters.rejected_inputs += 1
        self.reporter.report(key, reason, snippet)

    # ------------------------------------------------------------------ time

    def tick(self, now: float) -> None:
        """Run every timer that is due at ``now``."""
        self._now = now
        for lost in self.exchange.expire(now):
            self._on_result(lost)
        control, log = self.links["control"], self.links["log"]
        if control.connected and control.waiting_since is not None and now >= control.waiting_since + self.settings.silence_timeout:
            self._events.append(DropLink("control", f"robot silent: no reply for {self.settings.silence_timeout:.3g} s"))
            control.waiting_since = None
        if log.connected and now >= log.last_rx + self.settings.log_silence_timeout:
            self._events.append(DropLink("log", f"no state report for {self.settings.log_silence_timeout:.3g} s"))
            log.last_rx = now
        if control.connected and self._prepare_at is not None and now >= self._prepare_at:
            self._prepare_at = None
            self._send(wire.simple(CommandCode.PREPARE_WHEEL_CONTROLLER), now)
        if control.connected and now >= self._next_poll:
            self._poll(now)
            self._next_poll += self._period
            if self._next_poll < now - self._period:  # fell behind (loaded machine): resynchronise, no burst
                self._next_poll = now + self._period
        if now < self._conflict_until:
            self._report_conflict(now)
        elif self.conflict_with is not None:
            self.conflict_with = None
            self.reporter.report(self.keys.health, "the other gateway on this prefix is gone: commands accepted again")
        if now >= self._next_health:
            self._events.append(self.health(now))
            self.reporter.flush()
            self._next_health = now + self.settings.health_period
        self._pump(now)

    def stop_robot(self, now: float) -> None:
        """Leave the robot standing: zero velocity and NORMAL_STOP, ahead of nothing else."""
        self._now = now
        self.stopping = True
        if self.links["control"].connected:
            self._send(wire.set_velocity(0.0, 0.0), now)
            self._send(wire.simple(CommandCode.NORMAL_STOP), now)
            self.counters.commands_sent += 2

    @property
    def idle(self) -> bool:
        """No request is waiting for its reply."""
        return not self.exchange.outstanding

    # ------------------------------------------------------------------ health

    def health(self, now: float) -> GatewayHealth:
        window = [t for t in self._poll_times if now - t <= 2.0]
        rate = (len(window) - 1) / max(window[-1] - window[0], 1e-9) if len(window) >= 2 else 0.0
        c = self.counters
        accepted = self.governor.accepted
        return GatewayHealth(
            stamp=self.wallclock(),
            control=self.links["control"].health(),
            log=self.links["log"].health(),
            commands_sent=c.commands_sent,
            polls=c.polls,
            replies=c.replies,
            full_buffer=c.full_buffer,
            full_buffer_retries=c.full_buffer_retries,
            malformed_replies=c.malformed_replies,
            garbage_bytes=sum(d.garbage_bytes for d in self._decoders.values()),
            rejected_inputs=c.rejected_inputs,
            keepalives=c.keepalives,
            lost_replies=c.lost_replies,
            polls_skipped=c.polls_skipped,
            estop=self.governor.estop,
            cmd_timeout_active=self.governor.link_up and self.governor.timed_out(now),
            last_rtt_ms=None if self.last_rtt is None else round(self.last_rtt * 1000, 3),
            poll_hz=round(rate, 2),
            wheel_speeds=(0.0, 0.0) if accepted is None else (accepted.left, accepted.right),
            source=self.source,
            conflict_with=self.conflict_with if now < self._conflict_until else None,
        )

    # ------------------------------------------------------------------ sending

    def _send(self, request: wire.Request, now: float) -> bool:
        if not self.links["control"].connected:
            return False
        data = wire.encode_request(request)  # raises on anything the robot must not see
        if self.exchange.in_doubt and _is_stop(request):
            # a stop cannot wait for doubtful replies to settle: give them up, so the stop's own reply pairs with it
            self.counters.lost_replies += self.exchange.forget_expired()
        self._outgoing["control"] += data
        self.exchange.sent(request, now)
        state = self.links["control"]
        if state.waiting_since is None:
            state.waiting_since = now
        return True

    def _pump(self, now: float) -> None:
        """Send whatever the safety state wants sent now: EMG_STOP first, then velocity."""
        if not self.links["control"].connected or self.stopping:
            return
        gov = self.governor
        if gov.emg_stop_due(now) and self._send(wire.simple(CommandCode.EMG_STOP), now):
            gov.on_emg_stop_sent()
            self.counters.commands_sent += 1
        command = gov.next_command(now, congested=self._congested())
        if command is not None and self._send(wire.set_velocity(command.wheels.right, command.wheels.left), now):
            self.counters.commands_sent += 1
            if command.reason == "keepalive":
                self.counters.keepalives += 1
            elif command.reason == "retry":
                self.counters.full_buffer_retries += 1
            elif command.reason == "stop-again":
                self.reporter.report(
                    self._robot["control"],
                    "robot wheels still turn although it accepted a stop: asking it to stop again",
                    source="robot",
                )

    def _congested(self) -> bool:
        """Only stops go out: the robot is behind, or a reply is in doubt (late or lost) and pairing must settle."""
        return self.exchange.in_doubt or len(self.exchange.outstanding) >= MAX_IN_FLIGHT

    def _poll(self, now: float) -> None:
        if self.exchange.polls_in_flight() or self._congested():
            self.counters.polls_skipped += 1  # never build a backlog of polls
            return
        if self._send(wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY), now):
            self.counters.polls += 1

    # ------------------------------------------------------------------ receiving

    def _receive_control(self, data: bytes, now: float) -> None:
        for item in self._decoders["control"].feed(data):
            if isinstance(item, Malformed):
                self.counters.malformed_replies += 1
                self.reporter.report(self._robot["control"], f"malformed reply from the robot: {item.reason}", excerpt(item.raw), "robot")
                continue
            self.counters.replies += 1
            for result in self.exchange.received(item, now):
                self._on_result(result)
        self._pump(now)

    def _on_result(self, result: Completed | Lost) -> None:
        request = result.request
        command = request.command
        now = self._now
        if isinstance(result, Lost):
            self.counters.lost_replies += 1
            self._not_taken(request, now)
            return
        self.last_rtt = result.rtt
        if result.late:
            self.reporter.report(
                self._robot["control"],
                f"robot slow: a reply came {1000 * result.rtt:.0f} ms after its request "
                f"(reply timeout {1000 * self.settings.reply_timeout:.0f} ms); polling waits for it",
                source="robot",
            )
        if result.status.full_buffer:
            self.counters.full_buffer += 1
            self._not_taken(request, now)
            return
        if not result.status.ok:
            self.reporter.report(self._robot["control"], f"unknown status {result.status.status!r} from the robot", source="robot")
        if command is CommandCode.SET_LR_WHEEL_VELOCITY:
            self.governor.on_accepted(_wheels(request), now)
        elif command is CommandCode.PREPARE_WHEEL_CONTROLLER:
            self._prepare_attempts = 0
        elif isinstance(result.data, wire.SpeedReading):
            reading = result.data
            self._events.append(
                WheelImpulses(seq=self.seq, stamp=self.wallclock(), left=reading.left, right=reading.right, mono=now, source=self.source)
            )
            self.seq += 1
            self._poll_times.append(now)
            self.governor.observe_motion(*NOMINAL_ENCODERS.to_speeds(float(reading.left), float(reading.right)), now)

    def _not_taken(self, request: wire.Request, now: float) -> None:
        """The robot dropped ``request`` (FULL_BUFFER) or did not answer in time: re-send what must be re-sent, spaced."""
        command = request.command
        if command is CommandCode.SET_LR_WHEEL_VELOCITY:
            reason = self.governor.on_dropped(_wheels(request), now)
            if reason is not None:
                self.reporter.report(self._robot["control"], reason, source="robot")
        elif command is CommandCode.EMG_STOP:
            self.governor.on_emg_stop_dropped(now)
        elif command is CommandCode.PREPARE_WHEEL_CONTROLLER and self._prepare_at is None:
            self._prepare_attempts += 1
            self._prepare_at = now + retry_delay(self._prepare_attempts)

    def _receive_log(self, data: bytes) -> None:
        for item in self._decoders["log"].feed(data):
            if isinstance(item, LogReport):
                stamp = self.wallclock()
                status = RobotStatus.from_codes(stamp, item.state, item.direction)
                last = self._last_status
                changed = last is None or (status.state, status.direction) != (last.state, last.direction)
                if changed or stamp - self._last_status_at >= 0.9:
                    self._events.append(status)
                    self._last_status_at = stamp
                self._last_status = status
            else:
                self.counters.malformed_replies += 1
                raw = excerpt(item.raw) if isinstance(item, Malformed) else repr(item)
                why = item.reason if isinstance(item, Malformed) else "unexpected message"
                self.reporter.report(self._robot["log"], f"log port: {why}", raw, "robot")
