"""The ROS 2 adapter's asyncio host: its core on the runtime's driver, and the one input taken on Zenoh's thread.

All decisions are in :class:`~blackmetal.ros2.core.Ros2Core`; the Zenoh
edge's table hands each input to a core method, which the
:class:`~blackmetal.runtime.driver.Driver` calls with ``now`` under the core
lock, and the driver's core timer runs ``core.tick`` at the core's next deadline.

One input is also taken on Zenoh's thread: ``/cmd_vel``
(:meth:`Ros2Host.direct`), when the core's lock is free, so that a
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

from blackmetal.runtime.driver import Driver

from .core import Ros2Core

log = logging.getLogger("blackmetal.ros2")


class Ros2Host:
    """Runs one :class:`Ros2Core` on the running asyncio loop; see the module docstring."""

    def __init__(self, core: Ros2Core, clock: Callable[[], float] = time.monotonic, supervised: bool = False) -> None:
        self.core = core
        self.clock = clock
        self.supervised = supervised
        self.driver = Driver(core, clock, supervised=supervised, name=core.keys.prefix, logger=log)
        #: Held by the loop whenever it is in the core; a Zenoh thread taking ``/cmd_vel`` directly only tries it.
        self.lock = self.driver.lock
        self.fail = self.driver.fail

    @property
    def running(self) -> bool:
        """The core serves (from its start until run ends or a bug failed it); direct takes only then."""
        return self.driver.serving

    def direct(self, stamped: bool = False) -> Callable[[bytes], bool]:
        """Zenoh's thread, under the lock (the intake's ``direct``): forward an acceptable command, else leave it to the loop.

        A command changes no deadline of the core: nothing to poke.
        """
        driver, take, clock = self.driver, self.core.take_cmd_vel, self.clock
        return lambda cdr: driver.may_take_directly() and take(cdr, clock(), stamped=stamped)

    async def run(self, stop: asyncio.Event) -> None:
        """Run the core's timers until ``stop`` (supervised: or until :meth:`fail`, raising the failure)."""
        with self.lock:
            self.core.start()
        self.driver.open()
        await self.driver.serve(stop)
