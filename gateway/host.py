"""The gateway's asyncio host: moves bytes between the robot's streams and the sans-I/O core.

All decisions are the :class:`~blackmetal.gateway.core.GatewayCore`'s; the runtime's :class:`~blackmetal.runtime.driver.Driver`
holds the core lock, timer, publishing and failure. A command or e-stop taken on Zenoh's thread (:meth:`GatewayHost.direct`)
leaves at once; threads and locks: ``docs/threads.md``.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import time
from collections.abc import Callable
from typing import Any

from blackmetal.runtime.driver import Driver
from blackmetal.schemas import DriverChange, ErrorReport, GatewayHealth, GatewayParams, RobotStatus, WheelImpulses, WheelPosition
from blackmetal.transport import ByteStream, Connector

from .core import GatewayCore
from .health import Counters
from .latch import LatchStore, start_latch
from .links import LINKS, DropLink, LinkName, LinkState, ReconnectBackoff
from .settings import GatewaySettings

log = logging.getLogger("blackmetal.gateway")


Message = WheelImpulses | WheelPosition | RobotStatus | GatewayHealth | ErrorReport | DriverChange | GatewayParams


class GatewayHost:
    """Runs one :class:`GatewayCore` on the running asyncio loop; see the module docstring."""

    def __init__(
        self,
        settings: GatewaySettings,
        connector: Connector,
        output: Callable[[Message], None],
        latch: LatchStore,
        clock: Callable[[], float] = time.monotonic,
        wallclock: Callable[[], float] = time.time,
    ) -> None:
        self.settings = settings
        self.connector = connector
        self.output = output
        self.clock = clock
        robot = {name: f"robot:{connector.describe(name)}" for name in LINKS}
        self.latch = latch  # read now, before the first command to the robot; saved on every change
        start, self.start_sentence = start_latch(latch, wallclock(), settings.unsafe_start_released)
        self.core = GatewayCore(settings, clock(), wallclock, robot, latch=start)
        if self.start_sentence is not None:
            log.warning("%s: %s", settings.prefix, self.start_sentence)
            self.core.started_engaged(self.start_sentence, clock())
        self._streams: dict[LinkName, ByteStream | None] = {name: None for name in LINKS}
        self._drop_reason: dict[LinkName, str] = {}
        self.driver = Driver(self.core, clock, after_locked=self._flush_locked, publish=self._publish, name=settings.prefix, logger=log)
        #: Held by whoever is in the core or writes to a stream: the loop, or a Zenoh thread taking a command directly.
        self.lock = self.driver.lock
        #: Bytes a direct take could not write at once; the loop writes them before anything newer.
        self._unsent = b""
        self._flush_scheduled = False

    @property
    def counters(self) -> Counters:
        return self.core.counters

    @property
    def control(self) -> LinkState:
        return self.core.links["control"]

    def health(self) -> GatewayHealth:
        """The health now, from a thread that does not hold the lock."""
        with self.lock:
            return self.core.health(self.clock())

    def _publish(self, message: Message) -> None:
        if isinstance(message, ErrorReport):
            log.warning("error on %s: %s", message.key, message.reason)
        self.output(message)

    def direct(self, method: Callable[..., object], *, unpack: bool = True) -> Callable[[Any], bool]:
        """An intake channel's direct take (the intake holds the lock): ``method(*item, now)``, its bytes sent at once.

        False unless the driver's rule allows it; the rest (reports, the next deadline) waits for the loop's flush.
        """
        driver, clock = self.driver, self.clock

        def take(item: Any) -> bool:
            if not driver.may_take_directly():
                return False
            if unpack:
                method(*item, clock())
            else:
                method(item, clock())
            self._send_now_locked()
            if self._save_latch_locked():  # after the EMG_STOP left; a release takes effect once saved
                self._send_now_locked()
            if not self._flush_scheduled:
                self._flush_scheduled = True
                driver.schedule(self._flush_after_direct)
            return True

        return take

    def _send_now_locked(self) -> None:
        """What the control stream is due, as far as it takes it now; the rest goes first in the loop's next write."""
        data = self._pending_locked()
        if data:
            stream = self._streams["control"]
            sent = stream.write_now(data) if stream is not None and not stream.is_closing() else 0
            if sent < len(data):
                self._unsent = data[sent:]

    def _flush_after_direct(self) -> None:
        """The loop, after a direct take: its reports, the rest of its bytes, the next deadline; a failure fails the host."""
        try:
            with self.lock:
                self._flush_scheduled = False
                self._flush_locked()
            self.driver.publish()
        except Exception as exc:
            self.driver.fail(exc)

    def _pending_locked(self) -> bytes:
        """What the control link is due, oldest first (a direct take's unsent rest, then the core's new bytes)."""
        data = self.core.take_outgoing("control")
        rest, self._unsent = self._unsent, b""
        return rest + data if rest else data

    def _flush_locked(self) -> None:
        """Write what the core wants written; act on drops; keep its messages for the driver to publish."""
        self._write_locked(self._pending_locked())
        if self._save_latch_locked():  # after the EMG_STOP left; a release takes effect once saved
            self._write_locked(self._pending_locked())
        events = self.core.take_events()
        if events:
            outbox = self.driver.outbox
            for event in events:
                if isinstance(event, DropLink):
                    stream = self._streams[event.link]
                    if stream is not None and not stream.is_closing():
                        log.warning("%s link: dropping connection: %s", event.link, event.reason)
                        self._drop_reason[event.link] = event.reason
                        stream.close()
                else:
                    outbox.append(event)
        self.driver.timer.poke()

    def _write_locked(self, data: bytes) -> None:
        if data:
            stream = self._streams["control"]
            if stream is not None and not stream.is_closing():
                stream.write(data)

    def _save_latch_locked(self) -> bool:
        """Once the bytes of the input are written: save a change of the e-stop latch (True: there was one).

        Saved under the lock so that no health is built between the change and its save: health never shows an
        engaged stop that a restart would not find.
        """
        latch = self.core.take_latch()
        if latch is None:
            return False
        self.core.latch_saved(latch, self.latch.save(latch), self.clock())
        return True

    async def _run_link(self, name: LinkName, stop: asyncio.Event) -> None:
        """Connect, read until the stream ends, reconnect with backoff; until ``stop`` is set."""
        core, lock, driver = self.core, self.lock, self.driver
        backoff = ReconnectBackoff()
        first_failure = True
        while not stop.is_set():
            with lock:
                core.links.connecting(name)
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
            driver.take(core.link_up, name)
            reason = "closed by the robot"
            try:  # a bug in the core raises here, and the link's task fails with it
                await stream.pump(functools.partial(driver.take, core.receive, name))
            except (ConnectionError, OSError) as exc:
                reason = f"connection error: {exc}"
            finally:
                with lock:  # nobody writes to it from now on, from any thread
                    self._streams[name] = None
                    if name == "control":
                        self._unsent = b""
                    stream.close()
            reason = self._drop_reason.pop(name, reason)
            if stop.is_set():
                reason = "gateway stopping"
            else:
                log.warning("%s link: %s; reconnecting", name, reason)
            driver.take(core.link_down, name, reason)
            if not stop.is_set():
                await _sleep_or_stop(stop, backoff.failed(self.clock()))

    async def run(self, stop: asyncio.Event) -> None:
        """Run until ``stop`` is set (or the driver fails: raised here), then stop the robot and close the links."""
        link_stop = asyncio.Event()
        self.driver.open()
        tasks = [asyncio.create_task(self._run_link(name, link_stop), name=f"{name}-link") for name in LINKS]
        try:
            await self.driver.serve(stop, tasks)  # from its end on the loop takes every input (the core refuses motion once stopping)
        finally:
            await self._stop_robot()
            link_stop.set()
            with self.lock:
                for stream in self._streams.values():
                    if stream is not None:
                        stream.close()
            await asyncio.wait(tasks, timeout=1.0)
            for task in tasks:
                task.cancel()

    async def _stop_robot(self) -> None:
        """Zero velocity and NORMAL_STOP, so the robot is left standing; wait briefly for the replies."""
        self.driver.take(self.core.stop_robot)
        stream = self._streams["control"]
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
