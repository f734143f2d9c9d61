"""The odometry's asyncio host: stamps each input with the clock, counts dropped input, and pokes the shared
:class:`~blackmetal.runtime.driver.CoreTimer` that runs the core's tick; every decision is the core's.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

from blackmetal.runtime.driver import CoreTimer
from blackmetal.schemas import Pose

from .core import OdometryCore


class OdometryHost:
    def __init__(self, core: OdometryCore, clock: Callable[[], float] = time.monotonic) -> None:
        self.core = core
        self.clock = clock
        self.timer = CoreTimer(core, clock)
        self._dropped: Callable[[], int] = lambda: 0
        self._dropped_seen = 0

    def on_impulses(self, payload: bytes) -> None:
        now = self.clock()
        self.core.on_impulses(payload, now)
        dropped = self._dropped()  # samples are dropped only while others wait: the next one counts them
        if dropped > self._dropped_seen:
            self.core.on_dropped(dropped - self._dropped_seen, now)
            self._dropped_seen = dropped
        self.timer.poke()

    def on_reset(self, payload: bytes | None) -> Pose:
        """The core's reset; PayloadError (reported by the core) for a payload that is not a usable pose."""
        try:
            return self.core.on_reset(payload, self.clock())
        finally:
            self.timer.poke()

    async def run(self, stop: asyncio.Event, dropped: Callable[[], int] = lambda: 0) -> None:
        """Run the core's timers until ``stop``; ``dropped``: how many impulse samples the input has dropped so far."""
        self._dropped = dropped
        self.timer.start()
        try:
            await stop.wait()
        finally:
            self.timer.stop()
