"""The timer every service host runs its pure core on: one asyncio timer at the core's next deadline.

A core (the gateway's robot connection, the odometry, the ROS 2 adapter) is
pure and clock-injected: it is fed inputs with ``now``, runs its due timers
in ``tick(now)`` and says in ``next_deadline()`` when that must happen next.
:class:`DeadlineTimer` is the one piece of asyncio they share: it calls
``tick`` at the deadline, then ``after_tick`` (the host moves what the core
produced), and after each input the host calls :meth:`DeadlineTimer.poke`
so a deadline that came earlier is honoured. The timer is moved only when a
deadline comes earlier, so a flood of inputs costs no timer churn. A
core that other threads also drive (the gateway's) gives its ``lock``: the
timer holds it while it ticks, moves what the tick produced and schedules
the next deadline.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import threading
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Protocol

#: A deadline further away than this is slept in steps (asyncio's call_later wants a finite delay).
MAX_SLEEP_S = 3600.0
#: Timers are set in whole milliseconds, rounded up: uvloop (libuv) counts a delay in whole milliseconds, rounded to
#: the nearest, from a loop time it caches, so a deadline 0.4 ms away fired at once, 1.4 ms away after 1 ms, and the
#: core's tick found nothing due and set the timer again. At 100 robots x 50 Hz that was 30 % of the fleet gateway's
#: ticks (4 % after rounding up, which the cached loop time still brings early). A deadline is met at most 1 ms late.
TIMER_RESOLUTION_S = 0.001


class CoreLock:
    """The lock of a core that more than one thread drives (the gateway's): re-entrant, and it knows its holder.

    The loop holds it whenever it is in the core; a Zenoh thread taking an
    input directly only tries it. :meth:`held` lets the loop defer what must
    not happen under it (publishing to Zenoh, which may block) until the
    outermost holder lets go.
    """

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self._owner = 0
        self._depth = 0

    def acquire(self, blocking: bool = True) -> bool:
        if not self._lock.acquire(blocking):
            return False
        self._owner = threading.get_ident()
        self._depth += 1
        return True

    def release(self) -> None:
        self._depth -= 1
        if self._depth == 0:
            self._owner = 0
        self._lock.release()

    # acquire and release written out again: the loop enters this lock twice per poll per robot
    def __enter__(self) -> CoreLock:
        self._lock.acquire()
        self._owner = threading.get_ident()
        self._depth += 1
        return self

    def __exit__(self, *exc: object) -> None:
        self._depth -= 1
        if self._depth == 0:
            self._owner = 0
        self._lock.release()

    def held(self) -> bool:
        """Whether the calling thread holds it."""
        return self._owner == threading.get_ident()


class Core(Protocol):
    """What a host needs of a pure core to run its timers."""

    def tick(self, now: float) -> None: ...
    def next_deadline(self) -> float: ...


class DeadlineTimer:
    """Runs ``core.tick`` at ``core.next_deadline()`` on the running loop; see the module docstring."""

    def __init__(
        self,
        core: Core,
        clock: Callable[[], float] = time.monotonic,
        after_tick: Callable[[], None] | None = None,
        on_error: Callable[[BaseException], None] | None = None,
        lock: AbstractContextManager[object] | None = None,
        after_unlock: Callable[[], None] | None = None,
    ) -> None:
        self.core = core
        self.lock = lock if lock is not None else contextlib.nullcontext()
        self.clock = clock
        self.after_tick = after_tick
        #: Called after each tick once ``lock`` is released (the gateway publishes what the tick produced).
        self.after_unlock = after_unlock
        #: Called (and the timer stopped) when tick or after_tick raise: a host supervises its core through it.
        self.on_error = on_error
        self._timer: asyncio.TimerHandle | None = None
        self._timer_at = math.inf
        self._running = False

    def start(self) -> None:
        """Run the core's due timers now and keep running them at each deadline until :meth:`stop`."""
        self._running = True
        self._fire()

    def stop(self) -> None:
        self._running = False
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._timer_at = math.inf

    def poke(self) -> None:
        """An input reached the core: move the timer if its deadline came earlier."""
        if self._running:
            deadline = self.core.next_deadline()
            if deadline < self._timer_at:
                self._schedule(deadline)

    def _schedule(self, deadline: float) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer_at = deadline
        delay = math.ceil(min(max(deadline - self.clock(), 0.0), MAX_SLEEP_S) / TIMER_RESOLUTION_S) * TIMER_RESOLUTION_S
        self._timer = asyncio.get_running_loop().call_later(delay, self._fire)

    def _fire(self) -> None:
        self._timer = None
        self._timer_at = math.inf
        if not self._running:
            return
        try:
            with self.lock:
                self.core.tick(self.clock())  # now read inside the lock: a core never sees time go back
                if self.after_tick is not None:
                    self.after_tick()  # may poke: then the timer is already set
                if self._timer is None and self._running:
                    self._schedule(self.core.next_deadline())
            if self.after_unlock is not None:
                self.after_unlock()
        except Exception as exc:
            if self.on_error is None:
                raise
            self.stop()
            self.on_error(exc)
