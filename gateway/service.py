"""The gateway's core loop: robot links, safety and polling, between two thin edges.

Runs on one asyncio loop. Inputs arrive as bytes (from the Zenoh edge via
``loop.call_soon_threadsafe``, never inside a Zenoh callback); outputs
leave through a :class:`GatewayOutput` (the Zenoh edge, or a recorder in
tests); the robot is reached through a :class:`~gateway.link.Connector`.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from schemas import (
    EStop,
    ErrorReport,
    GatewayHealth,
    LinkHealth,
    PayloadError,
    RobotStatus,
    Twist,
    WheelImpulses,
    decode,
    excerpt,
)

from . import protocol
from .exchange import Completed, Exchange, Lost
from .kinematics import WheelSpeeds
from .link import Connector, Link
from .protocol import Command, LogReport, Malformed, ReplyDecoder
from .ratelimit import ReportLimiter
from .safety import Governor
from .settings import GatewaySettings

log = logging.getLogger("blackmetal.gateway")


class GatewayOutput(Protocol):
    """Where the gateway's messages go."""

    def impulses(self, message: WheelImpulses) -> None: ...
    def status(self, message: RobotStatus) -> None: ...
    def health(self, message: GatewayHealth) -> None: ...
    def error(self, message: ErrorReport) -> None: ...


@dataclass
class RecordingOutput:
    """A GatewayOutput that keeps everything, for tests and tools."""

    impulse_log: list[WheelImpulses] = field(default_factory=list)
    status_log: list[RobotStatus] = field(default_factory=list)
    health_log: list[GatewayHealth] = field(default_factory=list)
    error_log: list[ErrorReport] = field(default_factory=list)

    def impulses(self, message: WheelImpulses) -> None:
        self.impulse_log.append(message)

    def status(self, message: RobotStatus) -> None:
        self.status_log.append(message)

    def health(self, message: GatewayHealth) -> None:
        self.health_log.append(message)

    def error(self, message: ErrorReport) -> None:
        self.error_log.append(message)


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
    impulses_published: int = 0


class GatewayService:
    """Owns the robot links and the safety state; see the module docstring."""

    def __init__(
        self,
        settings: GatewaySettings,
        connector: Connector,
        output: GatewayOutput,
        clock: Callable[[], float] = time.monotonic,
        wallclock: Callable[[], float] = time.time,
    ) -> None:
        self.settings = settings
        self.output = output
        self.clock = clock
        self.wallclock = wallclock
        self.counters = Counters()
        self.governor = Governor(settings.safety(), clock())
        self.exchange = Exchange(reply_timeout=settings.reply_timeout)
        self.limiter = ReportLimiter()
        self.last_rtt: float | None = None
        self.seq = 0
        self._control_decoder = ReplyDecoder()
        self._log_decoder = ReplyDecoder()
        self._last_status: RobotStatus | None = None
        self._last_status_at = -1e9
        self._poll_times: list[float] = []
        self._stopping = False
        self._pump_timer: asyncio.TimerHandle | None = None
        self._cmd_key = f"{settings.prefix}/cmd_vel"
        self._estop_key = f"{settings.prefix}/estop"
        self._robot_key = f"robot:{connector.describe('control')}"
        self.control = Link(
            "control",
            connector,
            self._on_control_connected,
            self._on_control_data,
            self._on_control_down,
            settings.silence_timeout,
            clock,
            wallclock,
        )
        self.log_link = Link(
            "log",
            connector,
            self._on_log_connected,
            self._on_log_data,
            lambda reason: None,
            settings.log_silence_timeout,
            clock,
            wallclock,
        )

    # ------------------------------------------------------------------ Zenoh inputs (on the loop)

    def on_cmd_vel(self, payload: bytes) -> None:
        now = self.clock()
        try:
            twist = decode(Twist, payload)
        except PayloadError as exc:
            self.reject(self._cmd_key, str(exc), exc.excerpt)
            return
        reason = self.governor.on_twist(twist, now)
        if reason is not None:
            self.reject(self._cmd_key, reason, excerpt(payload))
            return
        self._pump(now)

    def on_estop(self, payload: bytes) -> None:
        try:
            estop = decode(EStop, payload)
        except PayloadError as exc:
            self.reject(self._estop_key, str(exc), exc.excerpt)
            return
        if estop.engaged != self.governor.estop:
            log.warning("emergency stop %s", "ENGAGED" if estop.engaged else "released")
        self.governor.on_estop(estop.engaged)
        self._pump(self.clock())
        self._publish_health()

    def reject(self, key: str, reason: str, snippet: str = "", source: str = "gateway") -> None:
        """Report a rejected input on ``<prefix>/errors`` (rate-limited per key)."""
        self.counters.rejected_inputs += 1
        self._report(key, reason, snippet, source)

    def _report(self, key: str, reason: str, snippet: str = "", source: str = "gateway") -> None:
        admitted, suppressed = self.limiter.admit(key, self.clock())
        if admitted:
            self.output.error(
                ErrorReport(
                    stamp=self.wallclock(), source=source, key=key, reason=reason, excerpt=snippet, suppressed=suppressed
                )
            )

    # ------------------------------------------------------------------ sending

    def _send(self, request: protocol.Request) -> bool:
        data = protocol.encode_request(request)  # raises on anything the robot must not see
        if not self.control.write(data):
            return False
        self.exchange.sent(request, self.clock())
        return True

    def _pump(self, now: float) -> None:
        """Send whatever the safety state wants sent now: EMG_STOP first, then velocity."""
        if not self.control.connected:
            return
        gov = self.governor
        if gov.emg_stop_needed:
            if self._send(protocol.simple(Command.EMG_STOP)):
                gov.emg_stop_needed = False
                self.counters.commands_sent += 1
        command = gov.next_command(now)
        if gov.hold_until is not None and self._pump_timer is None:
            self._pump_timer = asyncio.get_running_loop().call_later(max(gov.hold_until - now, 0.0), self._pump_later)
        if command is not None:
            wheels = command.wheels
            if self._send(protocol.set_velocity(wheels.right, wheels.left)):
                self.counters.commands_sent += 1
                if command.reason == "keepalive":
                    self.counters.keepalives += 1
                elif command.reason == "retry":
                    self.counters.full_buffer_retries += 1

    def _pump_later(self) -> None:
        self._pump_timer = None
        self._pump(self.clock())

    def _poll(self) -> None:
        if not self.control.connected:
            return
        if self.exchange.polls_in_flight():
            self.counters.polls_skipped += 1  # never build a backlog of polls
            return
        if self._send(protocol.simple(Command.GET_LR_WHEEL_VELOCITY)):
            self.counters.polls += 1

    # ------------------------------------------------------------------ control link

    def _on_control_connected(self) -> None:
        self._control_decoder.reset()
        self.exchange.clear("reconnected")
        self._send(protocol.simple(Command.PREPARE_WHEEL_CONTROLLER))
        self.governor.on_link_up()
        self._pump(self.clock())

    def _on_control_down(self, reason: str) -> None:
        self.governor.on_link_down()
        lost = self.exchange.clear(reason)
        self.counters.lost_replies += len(lost)
        if not self._stopping:
            self._report(self._robot_key, f"control link down: {reason}", source="robot")

    def _on_control_data(self, data: bytes, stamp: float) -> None:
        now = self.clock()
        for item in self._control_decoder.feed(data):
            if isinstance(item, Malformed):
                self.counters.malformed_replies += 1
                self._report(self._robot_key, f"malformed reply from the robot: {item.reason}", excerpt(item.raw), "robot")
                continue
            self.counters.replies += 1
            for result in self.exchange.received(item, now):
                self._on_result(result, stamp)
        self._pump(now)

    def _on_result(self, result: Completed | Lost, stamp: float) -> None:
        request = result.request
        if isinstance(result, Lost):
            self.counters.lost_replies += 1
            if request.command is Command.SET_LR_WHEEL_VELOCITY:
                self.governor.on_full_buffer(WheelSpeeds(float(request.right or 0.0), float(request.left or 0.0)))
            elif request.command is Command.EMG_STOP:
                self.governor.on_emg_stop_dropped()
            return
        self.last_rtt = result.rtt
        if result.status.full_buffer:
            self.counters.full_buffer += 1
            if request.command is Command.SET_LR_WHEEL_VELOCITY:
                wheels = WheelSpeeds(float(request.right or 0.0), float(request.left or 0.0))
                if not self.governor.on_full_buffer(wheels):
                    self._report(self._robot_key, "robot buffer full: velocity command dropped, retries exhausted", source="robot")
            elif request.command is Command.EMG_STOP:
                self.governor.on_emg_stop_dropped()
            elif request.command is Command.PREPARE_WHEEL_CONTROLLER:
                self._send(protocol.simple(Command.PREPARE_WHEEL_CONTROLLER))
            return
        if not result.status.ok:
            self._report(self._robot_key, f"unknown status {result.status.status!r} from the robot", source="robot")
        if request.command is Command.SET_LR_WHEEL_VELOCITY:
            self.governor.on_acknowledged(WheelSpeeds(float(request.right or 0.0), float(request.left or 0.0)))
        elif isinstance(result.data, protocol.WheelSpeeds):
            self.output.impulses(WheelImpulses(seq=self.seq, stamp=stamp, left=result.data.left, right=result.data.right))
            self.seq += 1
            self.counters.impulses_published += 1
            self._poll_times.append(self.clock())

    # ------------------------------------------------------------------ log link

    def _on_log_connected(self) -> None:
        self._log_decoder.reset()

    def _on_log_data(self, data: bytes, stamp: float) -> None:
        for item in self._log_decoder.feed(data):
            if isinstance(item, LogReport):
                status = RobotStatus.from_codes(stamp, item.state, item.direction)
                changed = self._last_status is None or (
                    (status.state, status.direction) != (self._last_status.state, self._last_status.direction)
                )
                if changed or stamp - self._last_status_at >= 0.9:
                    self.output.status(status)
                    self._last_status_at = stamp
                self._last_status = status
            else:
                self.counters.malformed_replies += 1
                raw = excerpt(item.raw) if isinstance(item, Malformed) else repr(item)
                why = item.reason if isinstance(item, Malformed) else "unexpected message"
                self._report(f"robot:{self.log_link.connector.describe('log')}", f"log port: {why}", raw, "robot")

    # ------------------------------------------------------------------ health

    def health(self) -> GatewayHealth:
        now = self.clock()
        window = [t for t in self._poll_times if now - t <= 2.0]
        self._poll_times = window
        rate = 0.0
        if len(window) >= 2:
            rate = (len(window) - 1) / max(window[-1] - window[0], 1e-9)
        c = self.counters
        sent = self.governor.wheels_sent
        return GatewayHealth(
            stamp=self.wallclock(),
            control=LinkHealth(self.control.state, self.control.connected_since, self.control.reconnects),
            log=LinkHealth(self.log_link.state, self.log_link.connected_since, self.log_link.reconnects),
            commands_sent=c.commands_sent,
            polls=c.polls,
            replies=c.replies,
            full_buffer=c.full_buffer,
            full_buffer_retries=c.full_buffer_retries,
            malformed_replies=c.malformed_replies,
            garbage_bytes=self._control_decoder.garbage_bytes + self._log_decoder.garbage_bytes,
            rejected_inputs=c.rejected_inputs,
            keepalives=c.keepalives,
            estop=self.governor.estop,
            cmd_timeout_active=self.governor.link_up and self.governor.timed_out(now),
            last_rtt_ms=None if self.last_rtt is None else round(self.last_rtt * 1000, 3),
            poll_hz=round(rate, 2),
            wheel_speeds=(0.0, 0.0) if sent is None else (sent.left, sent.right),
        )

    def _publish_health(self) -> None:
        self.output.health(self.health())

    # ------------------------------------------------------------------ main loop

    async def run(self, stop: asyncio.Event) -> None:
        """Run until ``stop`` is set, then stop the robot and close the links."""
        link_stop = asyncio.Event()
        tasks = [
            asyncio.create_task(self.control.run(link_stop), name="control-link"),
            asyncio.create_task(self.log_link.run(link_stop), name="log-link"),
        ]
        try:
            await self._tick_loop(stop)
        finally:
            self._stopping = True
            await self._stop_robot()
            link_stop.set()
            self.control.drop("gateway stopping")
            self.log_link.drop("gateway stopping")
            await asyncio.wait(tasks, timeout=1.0)
            for task in tasks:
                task.cancel()

    async def _tick_loop(self, stop: asyncio.Event) -> None:
        period = 1.0 / self.settings.poll_hz
        next_tick = self.clock()
        next_health = next_tick
        while not stop.is_set():
            now = self.clock()
            self._tick(now)
            self._poll()
            if now >= next_health:
                self._publish_health()
                self._flush_suppressed()
                next_health = now + self.settings.health_period
            next_tick += period
            if next_tick < now - period:  # fell behind (loaded machine): resynchronise, no burst
                next_tick = now
            delay = next_tick - self.clock()
            if delay > 0:
                try:
                    await asyncio.wait_for(stop.wait(), delay)
                except (TimeoutError, asyncio.TimeoutError):
                    pass

    def _tick(self, now: float) -> None:
        for lost in self.exchange.expire(now):
            self._on_result(lost, self.wallclock())
        if self.control.connected and self.control.silent(now, expect_push=False):
            self.control.drop(f"robot silent: no reply for {self.settings.silence_timeout:.3g} s")
        if self.log_link.connected and self.log_link.silent(now, expect_push=True):
            self.log_link.drop(f"no state report for {self.settings.log_silence_timeout:.3g} s")
        self._pump(now)

    def _flush_suppressed(self) -> None:
        for key, suppressed in self.limiter.due_summaries(self.clock()):
            self.output.error(
                ErrorReport(
                    stamp=self.wallclock(),
                    source="gateway",
                    key=key,
                    reason=f"{suppressed} more reports on {key} were rate-limited",
                    suppressed=suppressed,
                )
            )

    async def _stop_robot(self) -> None:
        """Zero velocity and NORMAL_STOP, so the robot is left standing."""
        if not self.control.connected:
            return
        self._send(protocol.set_velocity(0.0, 0.0))
        self._send(protocol.simple(Command.NORMAL_STOP))
        self.counters.commands_sent += 2
        await self.control.drain(0.5)
        deadline = self.clock() + 0.3
        while self.exchange.outstanding and self.clock() < deadline:
            await asyncio.sleep(0.01)
