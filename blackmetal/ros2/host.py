"""The ROS 2 adapter's asyncio host: stamps each input with the clock and runs the core's timers.

All decisions are in :class:`~blackmetal.ros2.core.Ros2Core`; the Zenoh
edge hands payloads over to this host on the loop
(:mod:`blackmetal.runtime.edge`), the host passes them on with ``now`` and
pokes the shared :class:`~blackmetal.runtime.host.DeadlineTimer`, which runs
``core.tick`` at the core's next deadline. No timer of its own.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

from blackmetal.runtime.host import DeadlineTimer

from .core import Ros2Core


class Ros2Host:
    """Runs one :class:`Ros2Core` on the running asyncio loop; see the module docstring."""

    def __init__(self, core: Ros2Core, clock: Callable[[], float] = time.monotonic) -> None:
        self.core = core
        self.clock = clock
        self.timer = DeadlineTimer(core, clock)

    def on_pose(self, payload: bytes) -> None:
        self.core.on_pose(payload, self.clock())
        self.timer.poke()

    def on_impulses(self, payload: bytes) -> None:
        self.core.on_impulses(payload, self.clock())
        self.timer.poke()

    def on_cmd_vel(self, cdr: bytes) -> None:
        self.core.on_cmd_vel(cdr, self.clock())
        self.timer.poke()

    def on_estop(self, cdr: bytes) -> None:
        self.core.on_estop(cdr, self.clock())
        self.timer.poke()

    def on_health(self, payload: bytes) -> None:
        self.core.on_health(payload, self.clock())
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
        """Run the core's timers until ``stop``."""
        self.timer.start()
        try:
            await stop.wait()
        finally:
            self.timer.stop()
