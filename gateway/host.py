"""The gateway's asyncio host: moves bytes between the robot's streams and the sans-I/O connection, and sleeps.

All decisions are in :class:`~blackmetal.gateway.core.GatewayCore`; this
module opens the robot's streams through an injected
:class:`~blackmetal.transport.Connector` (TCP, or the simulator's memory
pipe in tests), reconnects with backoff, feeds what it reads, writes what
the connection wants written, hands messages to a :class:`GatewayOutput`,
and sleeps until the connection's next deadline or the next input
(:class:`~blackmetal.runtime.host.DeadlineTimer`, shared by every service).

Commands and e-stops may also be taken on the Zenoh thread that delivers
them (:meth:`GatewayHost.cmd_vel_direct`, :meth:`GatewayHost.estop_direct`),
through the one :class:`~blackmetal.gateway.direct.DirectPath`: its lock guards the core
and the streams' writes, the loop holds it whenever it is in the core, and
every ``now`` is read inside it, so the core never sees time go back. Messages are published
only on the loop and never under that lock (:meth:`GatewayHost.publish`):
a Zenoh put that blocks must not hold up an e-stop's direct take. The
threads and locks are drawn in ``docs/threads.md``.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from blackmetal.runtime.host import DeadlineTimer
from blackmetal.schemas import DriverChange, ErrorReport, GatewayHealth, GatewayParams, ParamsSetReply, RobotStatus, WheelImpulses
from blackmetal.transport import ByteStream, Connector

from .arbiter import DEFAULT_SOURCE
from .core import Event, GatewayCore
from .direct import DirectPath
from .health import Counters
from .latch import LatchStore, start_latch
from .links import LINKS, DropLink, LinkName, LinkState, ReconnectBackoff
from .settings import GatewaySettings

log = logging.getLogger("blackmetal.gateway")


class GatewayOutput(Protocol):
    """Where the gateway's messages go."""

    def impulses(self, message: WheelImpulses) -> None: ...
    def status(self, message: RobotStatus) -> None: ...
    def health(self, message: GatewayHealth) -> None: ...
    def error(self, message: ErrorReport) -> None: ...
    def driver(self, message: DriverChange) -> None: ...
    def params(self, message: GatewayParams) -> None: ...


@dataclass
class RecordingOutput:
    """A GatewayOutput that keeps everything, for tests and tools."""

    impulse_log: list[WheelImpulses] = field(default_factory=list)
    status_log: list[RobotStatus] = field(default_factory=list)
    health_log: list[GatewayHealth] = field(default_factory=list)
    error_log: list[ErrorReport] = field(default_factory=list)
    driver_log: list[DriverChange] = field(default_factory=list)
    params_log: list[GatewayParams] = field(default_factory=list)

    def impulses(self, message: WheelImpulses) -> None:
        self.impulse_log.append(message)

    def status(self, message: RobotStatus) -> None:
        self.status_log.append(message)

    def health(self, message: GatewayHealth) -> None:
        self.health_log.append(message)

    def error(self, message: ErrorReport) -> None:
        self.error_log.append(message)

    def driver(self, message: DriverChange) -> None:
        self.driver_log.append(message)

    def params(self, message: GatewayParams) -> None:
        self.params_log.append(message)


class GatewayHost:
    """Runs one :class:`GatewayCore` on the running asyncio loop; see the module docstring."""

    def __init__(
        self,
        settings: GatewaySettings,
        connector: Connector,
        output: GatewayOutput,
        latch: LatchStore,
        clock: Callable[[], float] = time.monotonic,
        wallclock: Callable[[], float] = time.time,
    ) -> None:
        self.settings = settings
        self.connector = connector
        self.output = output
        self.clock = clock
        robot = {name: f"robot:{connector.describe(name)}" for name in LINKS}
        #: Where the e-stop latch is kept; read now, before the first command to the robot, and saved on every change.
        self.latch = latch
        start, self.start_sentence = start_latch(latch, wallclock(), settings.unsafe_start_released)
        self.core = GatewayCore(settings, clock(), wallclock, robot, latch=start)
        if self.start_sentence is not None:
            log.warning("%s: %s", settings.prefix, self.start_sentence)
            self.core.started_engaged(self.start_sentence, clock())
        self._streams: dict[LinkName, ByteStream | None] = {name: None for name in LINKS}
        self._drop_reason: dict[LinkName, str] = {}
        #: The lock, the control stream and the send-now rule of inputs taken on a Zenoh thread (:mod:`blackmetal.gateway.direct`).
        self.direct = DirectPath()
        #: Held by whoever is in the core or writes to a stream: the loop, or a Zenoh thread taking a command directly.
        self.lock = self.direct.lock
        #: Messages the core produced, published by the loop once it holds no lock (:meth:`publish`).
        self._outbox: list[Event] = []
        self._timer = DeadlineTimer(self.core, clock, after_tick=self._flush, on_error=self.fail, lock=self.lock, after_unlock=self.publish)
        self._failure: asyncio.Future[None] | None = None

    # ------------------------------------------------------------------ what tests and the edge see

    @property
    def counters(self) -> Counters:
        return self.core.counters

    @property
    def control(self) -> LinkState:
        return self.core.links["control"]

    def health(self) -> GatewayHealth:
        with self.lock:
            return self.core.health(self.clock())

    def fail(self, exc: BaseException) -> None:
        """A bug in this robot's handling: :meth:`run` ends with it (after stopping the robot), for a supervisor to restart."""
        log.error("%s: %r", self.core.keys.prefix, exc, exc_info=exc)
        with self.lock:
            self.direct.shut()  # a core that raised is driven by nobody but the loop's stop from now on
        if self._failure is not None and not self._failure.done():
            self._failure.set_exception(exc)

    # The loop's inputs: each runs the core under the lock, then publishes what it produced once no lock is held.

    def _input(self, handle: Callable[..., object], *args: object) -> None:
        """The loop: ``handle(*args, now)`` on the core under the lock, the bytes it wants sent, then what it produced published."""
        with self.lock:
            handle(*args, self.clock())
            self._flush()
        self.publish()

    def on_cmd_vel(self, payload: bytes, source: str = DEFAULT_SOURCE) -> None:
        self._input(lambda now: self.core.on_cmd_vel(payload, now, source))

    def on_source_cmd_vel(self, item: tuple[str, bytes]) -> None:
        """``(source, payload)`` from ``<prefix>/cmd_vel/<source>``."""
        self.on_cmd_vel(item[1], item[0])

    def on_superseded(self, source: str, count: int) -> None:
        """``count`` commands of ``source`` were superseded in the intake before the loop took them."""
        self._input(self.core.on_superseded, source, count)

    def on_named_lock(self, item: tuple[str, bytes]) -> None:
        """``(name, payload)`` from ``<prefix>/lock/<name>``."""
        self._input(self.core.on_lock, item[0], item[1])

    def on_estop(self, payload: bytes, release_key: bool = False) -> None:
        """A payload on ``<prefix>/estop`` (``release_key``: on ``<prefix>/estop/release``)."""
        self._input(lambda now: self.core.on_estop(payload, now, release_key))

    def on_estop_input(self, item: tuple[bool, bytes]) -> None:
        """``(release_key, payload)`` from the e-stop channel, which both e-stop keys feed."""
        self.on_estop(item[1], item[0])

    def on_input_flood(self, key: str, reason: str) -> None:
        """An input began or stopped flooding (the edge changed how it takes it): reported on ``<prefix>/errors``."""
        self._input(self.core.note_input, key, reason)

    def on_health_seen(self, payload: bytes) -> None:
        self._input(self.core.on_health_seen, payload)

    def recent_errors(self) -> list[ErrorReport]:
        """The core's latest error reports, oldest first (a get on ``<prefix>/errors`` answers with them)."""
        with self.lock:
            return list(self.core.reporter.recent)

    def params(self) -> GatewayParams:
        with self.lock:
            return self.core.params_now()

    def set_params(self, payload: bytes) -> ParamsSetReply | str:
        """A get on ``<prefix>/gateway/params/set``: the core's answer (a str: why the payload is no ParamsSet)."""
        try:
            with self.lock:
                try:
                    return self.core.on_params_set(payload, self.clock())
                finally:
                    self._flush()
        finally:
            self.publish()

    # ------------------------------------------------------------------ taken on a Zenoh thread (Intake direct)

    def cmd_vel_direct(self, item: tuple[str, bytes]) -> bool:
        """Under :attr:`lock`, on the thread that delivered it: handle ``(source, payload)`` and send the result at once.

        False (the loop takes it, as any input) until the host runs. What
        the command produced besides the control link's bytes (reports, the
        next deadline) waits for the loop's flush, scheduled here.
        """
        if not self.direct.allowed():
            return False
        self.core.on_cmd_vel(item[1], self.clock(), item[0])
        self.direct.send(self._pending(), self._flush_locked)
        return True

    def estop_direct(self, item: tuple[bool, bytes]) -> bool:
        """As :meth:`cmd_vel_direct`, for ``(release_key, payload)``: EMG_STOP leaves for the robot without waiting for the loop."""
        if not self.direct.allowed():
            return False
        self.core.on_estop(item[1], self.clock(), item[0])
        self.direct.send(self._pending(), self._flush_locked)
        if self._save_latch():  # after the EMG_STOP left; a release takes effect once saved
            self.direct.send(self._pending(), self._flush_locked)
        return True

    def _flush_locked(self) -> None:
        """The loop, after a direct take: its reports, the rest of its bytes, the next deadline; a failure fails the host."""
        try:
            with self.lock:
                self.direct.flushed()
                self._flush()
            self.publish()
        except Exception as exc:
            self.fail(exc)

    # ------------------------------------------------------------------ moving bytes

    def _pending(self) -> bytes:
        """Under the lock: what the control link is to be sent, oldest first (a direct take's unsent rest, then the core's
        new bytes). Only the control link is ever written to: the log link is read-only."""
        return self.direct.before(self.core.take_outgoing("control"))

    def _flush(self) -> None:
        """Under the lock: write what the connection wants written; act on drops; keep its messages for :meth:`publish`.

        This runs twice per poll per robot.
        """
        core = self.core
        self._write(self._pending())
        if self._save_latch():  # after the EMG_STOP left; a release takes effect once saved
            self._write(self._pending())
        events = core.take_events()
        if events:
            for event in events:
                if isinstance(event, DropLink):
                    stream = self._streams[event.link]
                    if stream is not None and not stream.is_closing():
                        log.warning("%s link: dropping connection: %s", event.link, event.reason)
                        self._drop_reason[event.link] = event.reason
                        stream.close()
                else:
                    self._outbox.append(event)
        self._timer.poke()

    def _write(self, data: bytes) -> None:
        """Under the lock: ``data`` to the control stream, if it is open."""
        if data:
            stream = self._streams["control"]
            if stream is not None and not stream.is_closing():
                stream.write(data)

    def _save_latch(self) -> bool:
        """Under the lock, once the bytes of the input are written: save a change of the e-stop latch (True: there was one).

        Saved under the lock so that no health is built between the change and its save: health never shows an
        engaged stop that a restart would not find.
        """
        latch = self.core.take_latch()
        if latch is None:
            return False
        self.core.latch_saved(latch, self.latch.save(latch), self.clock())
        return True

    def publish(self) -> None:
        """The loop, holding no lock: hand the core's messages to the output (a put may block; no e-stop waits on it).

        Called while the loop still holds the lock (an input handled inside a
        drain), it leaves them for the outermost holder, which calls it again.
        """
        if not self._outbox or self.lock.held():
            return
        events, self._outbox = self._outbox, []
        output = self.output
        for event in events:
            if isinstance(event, WheelImpulses):
                output.impulses(event)
            elif isinstance(event, RobotStatus):
                output.status(event)
            elif isinstance(event, GatewayHealth):
                output.health(event)
            elif isinstance(event, ErrorReport):
                log.warning("error on %s: %s", event.key, event.reason)
                output.error(event)
            elif isinstance(event, DriverChange):
                output.driver(event)
            elif isinstance(event, GatewayParams):
                output.params(event)

    async def _run_link(self, name: LinkName, stop: asyncio.Event) -> None:
        """Connect, read until the stream ends, reconnect with backoff; until ``stop`` is set."""
        core = self.core
        lock = self.lock
        backoff = ReconnectBackoff()
        first_failure = True
        while not stop.is_set():
            with lock:
                core.link_connecting(name)
            try:
                stream = await self.connector.open(name)
            except (OSError, TimeoutError) as exc:
                reason = f"cannot connect to {self.connector.describe(name)}: {_reason(exc)}"
                with lock:
                    core.link_down(name, reason, self.clock())
                if first_failure:
                    log.warning("%s link: %s; retrying", name, reason)
                    first_failure = False
                await _sleep_or_stop(stop, backoff.failed(self.clock()))
                continue
            first_failure = True
            backoff.opened(self.clock())
            log.info("%s link: connected to %s", name, self.connector.describe(name))
            with lock:
                self._streams[name] = stream
                if name == "control":
                    self.direct.stream_up(stream)
                core.link_up(name, self.clock())
                self._flush()
            self.publish()
            reason = "closed by the robot"

            def deliver(data: bytes, name: LinkName = name) -> None:
                with lock:
                    core.receive(name, data, self.clock())
                    self._flush()
                self.publish()

            try:
                await stream.pump(deliver)  # a bug in the core raises here, and the link's task fails with it
            except (ConnectionError, OSError) as exc:
                reason = f"connection error: {exc}"
            finally:
                with lock:  # nobody writes to it from now on, from any thread
                    self._streams[name] = None
                    if name == "control":
                        self.direct.stream_down()
                    stream.close()
            reason = self._drop_reason.pop(name, reason)
            if stop.is_set():
                reason = "gateway stopping"
            else:
                log.warning("%s link: %s; reconnecting", name, reason)
            with lock:
                core.link_down(name, reason, self.clock())
                self._flush()
            self.publish()
            if not stop.is_set():
                await _sleep_or_stop(stop, backoff.failed(self.clock()))

    async def run(self, stop: asyncio.Event) -> None:
        """Run until ``stop`` is set, then stop the robot and close the links."""
        link_stop = asyncio.Event()
        with self.lock:
            self.direct.open(asyncio.get_running_loop())
        tasks = [asyncio.create_task(self._run_link(name, link_stop), name=f"{name}-link") for name in LINKS]
        failure: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._failure = failure
        for task in tasks:
            task.add_done_callback(self._link_done)
        self._timer.start()
        stopped: asyncio.Future[Any] = asyncio.ensure_future(stop.wait())
        try:
            await asyncio.wait({stopped, failure}, return_when=asyncio.FIRST_COMPLETED)
            if failure.done():
                failure.result()  # raises the failure, after the finally below has stopped the robot
        finally:
            with self.lock:
                self.direct.shut()  # from now on the loop takes every input (and the core refuses motion once stopping)
            stopped.cancel()
            self._timer.stop()
            await self._stop_robot()
            link_stop.set()
            with self.lock:
                for stream in self._streams.values():
                    if stream is not None:
                        stream.close()
            await asyncio.wait(tasks, timeout=1.0)
            for task in tasks:
                task.cancel()

    def _link_done(self, task: asyncio.Task[None]) -> None:
        """A link task that dies of a bug fails the host: it must not leave the robot unserved, silently."""
        if not task.cancelled() and task.exception() is not None:
            self.fail(task.exception())  # type: ignore[arg-type]

    async def _stop_robot(self) -> None:
        """Zero velocity and NORMAL_STOP, so the robot is left standing; wait briefly for the replies."""
        with self.lock:
            self.core.stop_robot(self.clock())
            self._flush()
            stream = self._streams["control"]
        self.publish()
        if stream is None:
            return
        try:
            await asyncio.wait_for(stream.drain(), 0.5)
        except (ConnectionError, TimeoutError):
            return
        deadline = self.clock() + 0.3
        while self.clock() < deadline and self._streams["control"] is not None:
            with self.lock:
                if self.core.idle:
                    return
            await asyncio.sleep(0.01)


def _reason(exc: BaseException) -> str:
    """An exception as the reason of a failure, never empty (a bare TimeoutError has no text)."""
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return str(exc) or type(exc).__name__


async def _sleep_or_stop(stop: asyncio.Event, delay: float) -> None:
    try:
        await asyncio.wait_for(stop.wait(), delay)
    except TimeoutError:
        pass
