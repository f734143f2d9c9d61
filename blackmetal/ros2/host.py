"""The ROS 2 adapter's asyncio host: stamps each input with the clock and runs the core's timers.

All decisions are in :class:`~blackmetal.ros2.core.Ros2Core`; the Zenoh
edge hands payloads over to this host on the loop
(:mod:`blackmetal.runtime.edge`), the host passes them on with ``now`` and
pokes the shared :class:`~blackmetal.runtime.host.DeadlineTimer`, which runs
``core.tick`` at the core's next deadline. No timer of its own.

One input is also taken on Zenoh's thread: ``/cmd_vel``
(:meth:`Ros2Host.cmd_vel_direct`), when the core's lock is free, so that a
ROS command costs the adapter no wake of its loop. The lock
(:attr:`Ros2Host.lock`) is held by the loop whenever it is in the core
(drains, ticks, the start). The command the direct take makes is put on that
thread with drop congestion control, as rmw_zenoh put it, so it never waits
on a link (:class:`~blackmetal.ros2.zenoh_edge.Ros2Zenoh`).

``supervised`` (``--fleet``, :mod:`blackmetal.ros2.fleet`): a bug in
handling an input or in the core's timers ends :meth:`Ros2Host.run` with
that exception, for the supervisor to report and start this robot again;
the other robots of the process go on. Unsupervised (one robot), such an
exception goes to the loop's handler as it always has.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from typing import Any

from blackmetal.runtime.host import CoreLock, DeadlineTimer

from .core import Ros2Core

log = logging.getLogger("blackmetal.ros2")


class Ros2Host:
    """Runs one :class:`Ros2Core` on the running asyncio loop; see the module docstring."""

    def __init__(self, core: Ros2Core, clock: Callable[[], float] = time.monotonic, supervised: bool = False) -> None:
        self.core = core
        self.clock = clock
        self.supervised = supervised
        #: Held by the loop whenever it is in the core; a Zenoh thread taking ``/cmd_vel`` directly only tries it.
        self.lock = CoreLock()
        self.timer = DeadlineTimer(core, clock, on_error=self.fail if supervised else None, lock=self.lock)
        #: Under the lock: the core serves (from its start until run ends or a bug failed it); direct takes only then.
        self.running = False
        self._failure: asyncio.Future[None] | None = None

    def fail(self, exc: BaseException) -> None:
        """A bug in this robot's handling (supervised): :meth:`run` ends with it, for the supervisor to start it again."""
        with self.lock:
            self.running = False  # a core that raised forwards nothing more from Zenoh's threads
        log.error("%s: %r", self.core.keys.prefix, exc, exc_info=exc)
        if self._failure is not None and not self._failure.done():
            self._failure.set_exception(exc)

    def on_pose(self, payload: bytes) -> None:
        self.core.on_pose(payload, self.clock())
        self.timer.poke()

    def on_impulses(self, payload: bytes) -> None:
        self.core.on_impulses(payload, self.clock())
        self.timer.poke()

    def on_cmd_vel(self, cdr: bytes) -> None:
        self.core.on_cmd_vel(cdr, self.clock())
        self.timer.poke()

    def on_cmd_vel_stamped(self, cdr: bytes) -> None:
        self.core.on_cmd_vel(cdr, self.clock(), stamped=True)
        self.timer.poke()

    # Zenoh's thread, under the lock (the intake's ``direct``): forward an acceptable command, else leave it to the loop.
    # A command changes no deadline of the core: nothing to poke.
    def cmd_vel_direct(self, cdr: bytes) -> bool:
        return self.running and self.core.take_cmd_vel(cdr, self.clock())

    def cmd_vel_stamped_direct(self, cdr: bytes) -> bool:
        return self.running and self.core.take_cmd_vel(cdr, self.clock(), stamped=True)

    def on_estop(self, cdr: bytes) -> None:
        self.core.on_estop(cdr, self.clock())
        self.timer.poke()

    def on_health(self, payload: bytes) -> None:
        self.core.on_health(payload, self.clock())
        self.timer.poke()

    def on_matched(self, topic: str, matched: bool) -> None:
        self.core.on_matched(topic, matched, self.clock())
        self.timer.poke()

    def on_params(self, payload: bytes) -> None:
        self.core.on_params(payload, self.clock())
        self.timer.poke()

    def on_error_report(self, payload: bytes) -> None:
        self.core.on_error_report(payload, self.clock())

    def on_alive(self, who: str, alive: bool) -> None:
        self.core.on_alive(who, alive, self.clock())

    def on_service_request(self, service: str, call: int, cdr: bytes, attachment: bytes | None) -> None:
        self.core.on_service_request(service, call, cdr, attachment, self.clock())
        self.timer.poke()

    def on_query_reply(self, tag: int, ok: bool, payload: bytes) -> None:
        self.core.on_query_reply(tag, ok, payload, self.clock())
        self.timer.poke()

    def on_query_done(self, tag: int) -> None:
        self.core.on_query_done(tag, self.clock())
        self.timer.poke()

    async def run(self, stop: asyncio.Event) -> None:
        """Run the core's timers until ``stop`` (supervised: or until :meth:`fail`, raising the failure)."""
        with self.lock:
            self.core.start()
            self.running = True
        try:
            await self._serve(stop)
        finally:
            with self.lock:
                self.running = False

    async def _serve(self, stop: asyncio.Event) -> None:
        if not self.supervised:
            self.timer.start()
            try:
                await stop.wait()
            finally:
                self.timer.stop()
            return
        failure: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._failure = failure
        stopped: asyncio.Future[Any] = asyncio.ensure_future(stop.wait())
        try:
            self.timer.start()
            await asyncio.wait({stopped, failure}, return_when=asyncio.FIRST_COMPLETED)
            if failure.done():
                failure.result()
        finally:
            stopped.cancel()
            self.timer.stop()
            self._failure = None
