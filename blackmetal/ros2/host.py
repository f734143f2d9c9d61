"""The ROS 2 adapter's asyncio host: its core on the runtime's driver, and ``/cmd_vel`` taken on Zenoh's thread.

The direct take (:meth:`Ros2Host.direct`) only tries the core lock, so a ROS command costs no wake of the loop; its
put drops rather than waits on a link. ``supervised`` (``--fleet``): a bug ends :meth:`Ros2Host.run` with that
exception, for the supervisor to restart this robot. Threads and locks: docs/threads.md.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable

from blackmetal.runtime.driver import Driver

from .core import Ros2Core

log = logging.getLogger("blackmetal.ros2")


class Ros2Host:
    """Runs one :class:`Ros2Core` on the running asyncio loop; see the module docstring."""

    def __init__(self, core: Ros2Core, supervised: bool = False) -> None:
        self.core = core
        self.driver = Driver(core, time.monotonic, supervised=supervised, name=core.keys.prefix, logger=log)
        #: Held by the loop whenever it is in the core; a Zenoh thread taking ``/cmd_vel`` directly only tries it.
        self.lock = self.driver.lock
        self.fail = self.driver.fail

    def direct(self, stamped: bool = False) -> Callable[[bytes], bool]:
        """Zenoh's thread, under the lock: forward an acceptable command, else leave it to the loop (no deadline changes)."""
        driver, take, clock = self.driver, self.core.take_cmd_vel, time.monotonic
        return lambda cdr: driver.may_take_directly() and take(cdr, clock(), stamped=stamped)

    async def run(self, stop: asyncio.Event) -> None:
        """Run the core's timers until ``stop`` (supervised: or until :meth:`fail`, raising the failure)."""
        with self.lock:
            self.core.start()
        self.driver.open()
        await self.driver.serve(stop)
