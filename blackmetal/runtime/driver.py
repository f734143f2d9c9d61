"""The service driver: what sits between Zenoh and a pure core, in one place, under one rule.

:class:`Driver` runs one pure, clock-injected core on the service's loop and
owns the core lock (:class:`CoreLock`, never re-entered), the core timer
(:class:`CoreTimer`), publishing once the lock is released, failure, and the
direct take's rule (:meth:`Driver.may_take_directly`): only the thread that
delivers a sample may take it directly, never the loop, never a pump
(:func:`queue_only`). The threads and locks: ``docs/threads.md``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable, Iterable
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from typing import Any, Protocol

log = logging.getLogger("blackmetal.runtime")

#: A deadline further away than this is slept in steps (asyncio's call_later wants a finite delay).
MAX_SLEEP_S = 3600.0
#: Timers are set in whole milliseconds, rounded up: uvloop (libuv) counts a delay in whole milliseconds, rounded to
#: the nearest, from a loop time it caches, so a deadline 0.4 ms away fired at once, 1.4 ms away after 1 ms, and the
#: core's tick found nothing due and set the timer again. At 100 robots x 50 Hz that was 30 % of the fleet gateway's
#: ticks (4 % after rounding up, which the cached loop time still brings early). A deadline is met at most 1 ms late.
TIMER_RESOLUTION_S = 0.001

_pump = threading.local()


def queue_only() -> None:
    """Mark the calling thread as a pump (:mod:`blackmetal.runtime.flood`): what it puts is only queued, never taken."""
    _pump.only_queues = True


def delivering() -> bool:
    """Whether the calling thread may take what it puts directly: it delivers samples (it is no pump)."""
    return not getattr(_pump, "only_queues", False)


class CoreLock:
    """The lock of a core: not re-entrant (entered twice by one thread it raises instead of deadlocking)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._owner = 0

    def acquire(self, blocking: bool = True) -> bool:
        if blocking and self._owner == threading.get_ident():
            raise RuntimeError("the core lock is not re-entrant: this thread holds it already")
        if not self._lock.acquire(blocking):
            return False
        self._owner = threading.get_ident()
        return True

    def release(self) -> None:
        self._owner = 0
        self._lock.release()

    def __enter__(self) -> CoreLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def held(self) -> bool:
        """Whether the calling thread holds it."""
        return self._owner == threading.get_ident()


class Core(Protocol):
    """What the timer needs of a pure core."""

    def tick(self, now: float) -> None: ...
    def next_deadline(self) -> float: ...


@dataclass(eq=False)
class CoreTimer:
    """Runs ``core.tick`` at ``core.next_deadline()`` on the running loop, holding ``lock``, then ``after_tick``.

    :meth:`poke` after each input moves the timer only when the deadline came earlier: a flood costs no timer churn.
    """

    core: Core
    clock: Callable[[], float] = time.monotonic
    after_tick: Callable[[], None] | None = None
    #: Called (and the timer stopped) when tick or after_tick raise: the driver fails through it.
    on_error: Callable[[BaseException], None] | None = None
    lock: AbstractContextManager[object] = field(default_factory=contextlib.nullcontext)
    after_unlock: Callable[[], None] | None = None
    _timer: asyncio.TimerHandle | None = field(default=None, init=False)
    _timer_at: float = field(default=math.inf, init=False)
    _running: bool = field(default=False, init=False)

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


class Driver:
    """Runs one pure core on the running loop; see the module docstring.

    ``after_locked`` (lock held) runs after every input and tick: the host moves what the core produced and pokes
    the timer. ``publish`` gets each message of :attr:`outbox` once no lock is held. ``supervised``: a failure ends
    :meth:`serve` (else it goes to the loop's exception handler).
    """

    def __init__(
        self,
        core: Core,
        clock: Callable[[], float] = time.monotonic,
        *,
        after_locked: Callable[[], None] | None = None,
        publish: Callable[[Any], None] | None = None,
        supervised: bool = True,
        name: str = "",
        logger: logging.Logger = log,
    ) -> None:
        self.core = core
        self.clock = clock
        self.name = name
        self.log = logger
        self.lock = CoreLock()
        self.after_locked = after_locked or self.poke
        self._publish = publish
        self.supervised = supervised
        self.timer = CoreTimer(
            core, clock, after_tick=self.after_locked, on_error=self.fail if supervised else None, lock=self.lock, after_unlock=self.publish
        )
        #: Messages the core produced, published by the loop once it holds no lock.
        self.outbox: list[Any] = []
        #: The loop's thread while the driver serves (0: it does not; every input then waits for the loop).
        self._loop_thread = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._failure: asyncio.Future[None] | None = None

    def poke(self) -> None:
        self.timer.poke()

    def handler(self, method: Callable[..., Any], *, unpack: bool = True) -> Callable[[Any], Any]:
        """An intake channel's handler (a drain holds the lock): ``method(*item, now)``, then ``after_locked``."""
        clock, after = self.clock, self.after_locked

        def handle(item: Any) -> Any:
            result = method(*item, clock()) if unpack else method(item, clock())
            after()
            return result

        return handle

    def run_locked(self, method: Callable[..., Any], *args: Any) -> Any:
        """The caller holds the lock (a drain): ``method(*args, now)``, then ``after_locked``; its result."""
        result = method(*args, self.clock())
        self.after_locked()
        return result

    def take(self, method: Callable[..., Any], *args: Any) -> Any:
        """The loop, holding no lock (between drains: a link's reads, a start): ``method(*args, now)`` under the lock,
        ``after_locked``, then what it produced published; its result."""
        with self.lock:
            result = method(*args, self.clock())
            self.after_locked()
        self.publish()
        return result

    @property
    def serving(self) -> bool:
        """Between :meth:`open` and the end of :meth:`serve` (or a failure)."""
        return self._loop_thread != 0

    def may_take_directly(self) -> bool:
        """The direct-take rule: the driver serves, and the caller delivered the sample (not the loop, not a pump)."""
        return self._loop_thread not in (0, threading.get_ident()) and delivering()

    def schedule(self, callback: Callable[[], None]) -> None:
        """Another thread: ``callback`` on the loop, soon (nothing if the loop is gone)."""
        loop = self._loop
        if loop is not None:
            with contextlib.suppress(RuntimeError):  # the loop is closed: the service is gone
                loop.call_soon_threadsafe(callback)

    def publish(self) -> None:
        """The loop, holding no lock: hand the core's messages to ``publish`` (a put may block; no e-stop waits on it)."""
        if not self.outbox:
            return
        messages, self.outbox = self.outbox, []
        publish = self._publish
        if publish is not None:
            for message in messages:
                publish(message)

    def fail(self, exc: BaseException) -> None:
        """A bug in handling this core: :meth:`serve` ends with it, for a supervisor to restart; no direct take from now on."""
        self.log.error("%s: %r", self.name, exc, exc_info=exc)
        if self.lock.held():  # a drain's handler failed: the drain holds it
            self._loop_thread = 0
        else:
            self.shut()
        if self._failure is not None and not self._failure.done():
            self._failure.set_exception(exc)

    def on_error(self) -> Callable[[BaseException], None] | None:
        """What an intake calls with a handler's exception: :meth:`fail` when supervised, else the loop's handler."""
        return self.fail if self.supervised else None

    def open(self) -> None:
        """The loop, as it starts serving: direct takes are allowed from now on."""
        self._loop = asyncio.get_running_loop()
        with self.lock:
            self._loop_thread = threading.get_ident()

    def shut(self) -> None:
        """From now on the loop takes every input."""
        with self.lock:
            self._loop_thread = 0

    async def serve(self, stop: asyncio.Event, tasks: Iterable[asyncio.Task[Any]] = ()) -> None:
        """Tick the core until ``stop`` or a failure (raised here; a task that dies of a bug is one); the timer stopped after."""
        failure: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._failure = failure
        for task in tasks:
            task.add_done_callback(self._task_done)
        stopped: asyncio.Future[Any] = asyncio.ensure_future(stop.wait())
        try:
            self.timer.start()
            await asyncio.wait({stopped, failure}, return_when=asyncio.FIRST_COMPLETED)
            if failure.done():
                failure.result()
        finally:
            self.shut()
            stopped.cancel()
            self.timer.stop()
            self._failure = None

    def _task_done(self, task: asyncio.Task[Any]) -> None:
        """A task that dies of a bug fails the driver: it must not leave the core unserved, silently."""
        if not task.cancelled() and task.exception() is not None:
            self.fail(task.exception())  # type: ignore[arg-type]
