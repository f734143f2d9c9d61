"""The gateway's core, sans I/O (as h11 is for HTTP): bytes, commands and ``now`` in; bytes, messages and a deadline out.

It composes the gateway's pure parts, each with its own deadline (docs/contributing.md "One shape for every service").
"""

from __future__ import annotations

from collections.abc import Callable

from blackmetal import wire
from blackmetal.robot_model import NOMINAL_ENCODERS, WheelSpeeds
from blackmetal.schemas import GatewayHealth, RobotStatus, WheelImpulses, excerpt
from blackmetal.wire import CommandCode, Malformed, ReplyDecoder

from .commands import Event
from .exchange import Completed, Exchange, Lost
from .latch import Latch
from .links import LinkName, Links
from .log_port import LogPort
from .moves import MoveInputs
from .polling import PollSchedule
from .prepare import PrepareRetry
from .safety import CommandReason
from .settings import GatewaySettings

#: Requests in flight (late ones included) beyond which only stops go out, and polls wait.
MAX_IN_FLIGHT = 8
#: The poll, sent 50-100 times a second per robot: one request object, its bytes encoded once.
_POLL = wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY)
_POLL_BYTES = wire.encode_request(_POLL)
#: The commands that move or stop the wheels (health's ``last_sent``; any but a position move's own ends that move).
_MOTION = frozenset({CommandCode.EMG_STOP, CommandCode.NORMAL_STOP, CommandCode.SET_LR_WHEEL_VELOCITY, CommandCode.SET_LR_WHEEL_POSITION})


def _is_stop(request: wire.Request) -> bool:
    if request.command in (CommandCode.EMG_STOP, CommandCode.NORMAL_STOP):
        return True
    return request.command is CommandCode.SET_LR_WHEEL_VELOCITY and request.left == 0.0 and request.right == 0.0


def _describe(request: wire.Request) -> str:
    """A motion command as health shows it: its name, and (left, right) m/s for a velocity, impulses for a position."""
    if request.command is CommandCode.SET_LR_WHEEL_VELOCITY:
        wheels = _wheels(request)
        return f"velocity {wheels.left:.3f} {wheels.right:.3f}"
    if request.command is CommandCode.SET_LR_WHEEL_POSITION:
        return f"position {request.left} {request.right}"
    return request.command.name


def _wheels(request: wire.Request) -> WheelSpeeds:
    return WheelSpeeds(left=float(request.left or 0.0), right=float(request.right or 0.0))


class GatewayCore(MoveInputs):
    """The robot's side (links, requests and replies, polls) and the health; ``robot`` names its link ends in reports."""

    def __init__(
        self,
        settings: GatewaySettings,
        now: float,
        wallclock: Callable[[], float],
        robot: dict[LinkName, str] | None = None,
        latch: Latch | None = None,
    ) -> None:
        super().__init__(settings, now, wallclock, latch)
        self.exchange = Exchange(reply_timeout=settings.reply_timeout, late_horizon=3 * settings.reply_timeout)
        self.links = Links(settings.silence_timeout, settings.log_silence_timeout)
        self.polls = PollSchedule(settings.poll_hz)
        #: A poll came due while the one before it was unanswered: it goes out as soon as that one's reading comes.
        self._poll_waiting = False
        self.prepare = PrepareRetry()
        self.last_rtt: float | None = None
        self.seq = 0
        self.stopping = False
        self._robot = robot or {"control": "robot:control", "log": "robot:log"}
        self._replies = ReplyDecoder()
        self._log_port = LogPort()
        self._outgoing = bytearray()  # to the control link; nothing is ever written to the log link
        self._next_health = now
        #: The last motion command written (not a poll), and when (Unix time): health says what the robot was sent.
        self._last_sent: tuple[wire.Request, float] | None = None

    def take_outgoing(self, link: LinkName) -> bytes:
        """Bytes to write to ``link`` now (each request complete, in order)."""
        data = self._outgoing
        if link != "control" or not data:
            return b""
        out = bytes(data)
        data.clear()
        return out

    def take_events(self) -> list[Event]:
        """Messages to publish and links to drop, in the order they arose (write the outgoing bytes first)."""
        if self._ended:
            self._flush_moves()
        if self._health_due is not None:
            self._events.append(self.health(self._health_due))
            self._health_due = None
        if not self._events:
            return []
        events = self._events.copy()  # the same list stays: the reporter appends to it
        self._events.clear()
        return events

    def next_deadline(self) -> float:
        """When :meth:`tick` must run next, at the latest (monotonic seconds): the earliest of the parts' deadlines."""
        deadline = min(
            self._next_health,
            self.exchange.next_expiry(),
            self.governor.next_deadline(self._congested()),
            self.links.next_deadline(),
            self.conflict.next_deadline(),
            self.reporter.next_deadline(),
            self.arbiter.next_deadline(),
        )
        if self.move is not None:  # (guarded here and below: the poll path runs 50 times a second per robot)
            deadline = min(deadline, self._move_deadline())
        if self.links.control.connected:
            deadline = min(deadline, self.polls.next_deadline(), self.prepare.next_deadline())
        return deadline

    def link_up(self, link: LinkName, now: float) -> None:
        """``link`` is connected (again): start clean."""
        down_for = self.links.up(link, now, self.wallclock())
        if down_for is not None:
            self._report_robot(link, f"{link} link up again after {down_for:.1f} s", now)
        if link == "log":
            self._log_port.decoder.reset()
            return
        self._replies.reset()
        self._outgoing.clear()
        self.exchange.clear("reconnected")
        self.prepare.reset()
        self._send(wire.simple(CommandCode.PREPARE_WHEEL_CONTROLLER), now)
        self.governor.on_link_up(now)
        self._poll_waiting = False
        self.polls.start(now)
        self._send_due(now)

    def link_down(self, link: LinkName, reason: str, now: float) -> None:
        """``link`` closed, or could not be opened; a robot that cannot be reached is said once per reason, not per retry."""
        before = self.links[link].reason
        was_up = self.links.down(link, now, reason)
        if not self.stopping and (was_up or reason != before):
            self._report_robot(link, f"{link} link down: {reason}" if was_up else f"{link} link: {reason}", now)
        if link == "control":
            self._outgoing.clear()
        if link == "control" and was_up:
            self._end_move(f"control link down: {reason}", now, None)
            self.governor.on_link_down()
            self.counters.lost_replies += len(self.exchange.clear(reason))
            self.polls.stop()
            self._poll_waiting = False
            self.prepare.cancel()

    def receive(self, link: LinkName, data: bytes, now: float) -> None:
        self.links.received(link, now)
        if link == "control":
            self._receive_control(data, now)
        else:
            self._receive_log(data, now)

    def tick(self, now: float) -> None:
        for lost in self.exchange.expire(now):
            self._on_result(lost, now)
        self._events.extend(self.links.due(now))
        control_up = self.links.control.connected
        if control_up and self.prepare.due(now):
            self._send(wire.simple(CommandCode.PREPARE_WHEEL_CONTROLLER), now)
        if control_up and self.polls.due(now):
            self._poll(now)
        self._conflict_news(self.conflict.tick(now), now)
        self._arbitrate(now)
        if self.move is not None:
            self._move_tick(now)
        if now >= self._next_health:
            self._events.append(self.health(now))
            self._next_health = now + self.settings.health_period
        self.reporter.tick(now)
        self._send_due(now)

    def stop_robot(self, now: float) -> None:
        """Leave the robot standing: zero velocity and NORMAL_STOP, ahead of nothing else."""
        self.stopping = True
        if self.links.control.connected:
            self._send(wire.set_velocity(left=0.0, right=0.0), now)
            self._send(wire.simple(CommandCode.NORMAL_STOP), now)
            self.counters.commands_sent += 2

    @property
    def idle(self) -> bool:
        """No request is waiting for its reply."""
        return not self.exchange.outstanding

    def health(self, now: float) -> GatewayHealth:
        """The state at ``now``, as one health message (every ``health_period`` s, at once after an e-stop, and to a ``get``)."""
        governor, arbiter, rtt = self.governor, self.arbiter, self.last_rtt
        accepted = governor.accepted
        return GatewayHealth(
            stamp=self.wallclock(),
            control=self.links.control.health(),
            log=self.links.log.health(),
            **vars(self.counters),
            garbage_bytes=self._replies.garbage_bytes + self._log_port.decoder.garbage_bytes,
            estop=governor.estop,
            estop_since=self.latch.since,
            estop_by=self.latch.by,
            cmd_timeout_active=governor.link_up and governor.timed_out(now),
            cmd_timeout=governor.settings.cmd_timeout,
            last_rtt_ms=None if rtt is None else round(rtt * 1000, 3),
            poll_hz=round(self.polls.rate(now), 2),
            wheel_speeds=(0.0, 0.0) if accepted is None else (accepted.left, accepted.right),
            source=self.run_token,
            conflict_with=self.conflict.with_whom(now),
            active_source=arbiter.active,
            sources=arbiter.source_health(now),
            locks=arbiter.lock_states(now),
            last_sent=None if self._last_sent is None else _describe(self._last_sent[0]),
            last_sent_stamp=None if self._last_sent is None else self._last_sent[1],
        )

    def _report_robot(self, link: LinkName, reason: str, now: float, snippet: str = "") -> None:
        """A fault of the robot's, reported under the robot's end of ``link``."""
        self.reporter.report(self._robot[link], reason, snippet, by="robot", now=now)

    def _send(self, request: wire.Request, now: float) -> bool:
        if not self.links.control.connected:
            return False
        data = _POLL_BYTES if request is _POLL else wire.encode_request(request)  # raises on anything the robot must not see
        if self.exchange.in_doubt and _is_stop(request):
            # a stop cannot wait for doubtful replies to settle: give them up, so the stop's own reply pairs with it
            self.counters.lost_replies += self.exchange.forget_expired()
        self._outgoing += data
        command = request.command
        if command is not CommandCode.GET_LR_WHEEL_VELOCITY and command in _MOTION:  # the poll first: 50 a second
            if self.move is not None and command is not CommandCode.SET_LR_WHEEL_POSITION:
                self._move_sent(request, now)  # the robot drops a position move for any other motion command
            self._last_sent = (request, self.wallclock())
        self.exchange.sent(request, now)
        self.links.request_sent(now)
        return True

    def _send_due(self, now: float) -> None:
        """Send whatever the safety state wants sent now: EMG_STOP first, then velocity."""
        if not self.links.control.connected or self.stopping:
            return
        gov = self.governor
        if gov.emg_stop_due(now) and self._send(wire.simple(CommandCode.EMG_STOP), now):
            gov.on_emg_stop_sent()
            self.counters.commands_sent += 1
        if self.move is not None:
            self._check_move(now)
        command = gov.next_command(now, congested=self._congested())
        if command is None or not self._send(wire.set_velocity(left=command.wheels.left, right=command.wheels.right), now):
            return
        self.counters.commands_sent += 1
        if command.reason is CommandReason.KEEPALIVE:
            self.counters.keepalives += 1
        elif command.reason is CommandReason.RETRY:
            self.counters.full_buffer_retries += 1
        elif command.reason is CommandReason.STOP_AGAIN:
            self._report_robot("control", "robot wheels still turn although it accepted a stop: asking it to stop again", now)

    def _congested(self) -> bool:
        """Only stops go out: the robot is behind, or a reply is in doubt (late or lost) and pairing must settle."""
        return self.exchange.in_doubt or len(self.exchange.outstanding) >= MAX_IN_FLIGHT

    def _poll(self, now: float) -> None:
        """A poll is due: sent now, or once the one in flight is read (polls never queue at the robot); skipped and counted
        when one already waits a whole period, or a reply is in doubt."""
        if self._congested():
            self.counters.polls_skipped += 1
            self._poll_waiting = False
            return
        if self.exchange.polls_in_flight():
            if self._poll_waiting:
                self.counters.polls_skipped += 1  # a whole period behind: this one is lost, the waiting one stays
            self._poll_waiting = True
            return
        self._poll_waiting = False
        if self._send(_POLL, now):
            self.counters.polls += 1
            if self.move is not None:
                self._after_velocity_poll(now)

    def _receive_control(self, data: bytes, now: float) -> None:
        for item in self._replies.feed(data):
            if isinstance(item, Malformed):
                self.counters.malformed_replies += 1
                self._report_robot("control", f"malformed reply from the robot: {item.reason}", now, excerpt(item.raw))
                continue
            self.counters.replies += 1
            for result in self.exchange.received(item, now):
                self._on_result(result, now)
        self._send_due(now)

    def _on_result(self, result: Completed | Lost, now: float) -> None:
        request = result.request
        command = request.command
        if isinstance(result, Lost):
            self.counters.lost_replies += 1
            self._not_taken(request, now, lost=True)
            return
        self.last_rtt = result.rtt
        if result.late:
            self._report_robot(
                "control",
                f"robot slow: a reply came {1000 * result.rtt:.0f} ms after its request "
                f"(reply timeout {1000 * self.settings.reply_timeout:.0f} ms); polling waits for it",
                now,
            )
        if result.status.full_buffer:
            self.counters.full_buffer += 1
            self._not_taken(request, now, lost=False)
            return
        if not result.status.ok:
            self._report_robot("control", f"unknown status {result.status.status!r} from the robot", now)
        if command is CommandCode.SET_LR_WHEEL_VELOCITY:
            self.governor.on_accepted(_wheels(request), now)
        elif command is CommandCode.PREPARE_WHEEL_CONTROLLER:
            self.prepare.taken()
        elif isinstance(result.data, wire.SpeedReading):
            reading = result.data
            self._events.append(
                WheelImpulses(seq=self.seq, stamp=self.wallclock(), left=reading.left, right=reading.right, mono=now, source=self.run_token)
            )
            self.seq += 1
            self.polls.reading(now)
            if self.move is None:  # while one runs the wheels move by the robot's own control: no stop to confirm
                self.governor.observe_motion(*NOMINAL_ENCODERS.to_speeds(float(reading.left), float(reading.right)), now)
            if self._poll_waiting:  # the poll that came due while this one was unanswered goes out now
                self._poll(now)
        elif isinstance(result.data, wire.PositionReading) or command is CommandCode.GET_LR_WHEEL_POSITION:
            self._on_position(result.data if isinstance(result.data, wire.PositionReading) else None, now)

    def _not_taken(self, request: wire.Request, now: float, lost: bool) -> None:
        """The robot dropped ``request`` (FULL_BUFFER) or did not answer in time (``lost``): re-send what must be re-sent, spaced."""
        command = request.command
        if command is CommandCode.SET_LR_WHEEL_VELOCITY:
            reason = self.governor.on_dropped(_wheels(request), now)
            if reason is not None:
                self._report_robot("control", reason, now)
        elif command is CommandCode.EMG_STOP:
            self.governor.on_emg_stop_dropped(now)
        elif command is CommandCode.PREPARE_WHEEL_CONTROLLER:
            self.prepare.dropped(now)
        elif command is CommandCode.GET_LR_WHEEL_POSITION:
            self._on_position(None, now)
        else:
            self._position_not_taken(request, lost, now)

    def _receive_log(self, data: bytes, now: float) -> None:
        for item in self._log_port.feed(data, self.wallclock()):
            if isinstance(item, RobotStatus):
                self._events.append(item)
            else:
                self.counters.malformed_replies += 1
                self._report_robot("log", f"log port: {item.reason}", now, excerpt(item.raw))
