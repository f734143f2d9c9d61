"""A service's one intake: every input reaches its core through here, bounded, and one owner drains it.

A Zenoh callback only puts its item in the input's bounded channel and wakes
the loop once per batch; the loop, the core's one owner, drains it by
priority. One exception: a ``direct`` channel's item may be taken in the
thread that delivers it, under the core's lock (:meth:`Intake.channel`,
the rule in :mod:`blackmetal.runtime.driver`). The threads and locks: ``docs/threads.md``.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import InitVar, dataclass, field
from typing import Any, Generic, TypeVar

from .driver import CoreLock, delivering

T = TypeVar("T")

#: A channel takes at most DIRECT_BURST items directly within DIRECT_WINDOW_S (200 a second); the rest wait for
#: the loop. Commanders at 10-100 Hz are all taken directly, and a burst cannot keep Zenoh's thread in handlers.
DIRECT_BURST = 20
DIRECT_WINDOW_S = 0.1


@dataclass(eq=False)
class Channel(Generic[T]):
    """One input of a service: items from any thread, handled on the loop in arrival order.

    ``latest``: one slot, a newer item supersedes the waiting one (counted in
    ``dropped``). ``latch(item)`` true marks an item that must be handled even
    when newer ones supersede it (an e-stop ON): the first such item since the
    last take waits in its own slot, is handled first, and drops every older
    item; the newest item still follows it (an OFF newer than the ON).
    """

    name: str
    handler: Callable[[T], None]
    capacity: InitVar[int]
    priority: int
    latch: Callable[[T], bool] | None = None
    on_dropped: Callable[[int], None] | None = None
    items: deque[T] = field(init=False)
    latched: T | None = None
    dropped: int = 0
    #: Dropped since the handler was last told (``on_dropped``).
    unreported: int = 0
    received: int = 0
    #: Items taken directly (in the putting thread), and the current window of the direct budget.
    direct_taken: int = 0
    window_start: float = -math.inf
    window_direct: int = 0
    #: The channels of this priority or higher, itself included: a direct take waits behind what they hold.
    ahead: list[Channel[Any]] = field(default_factory=list)

    def __post_init__(self, capacity: int) -> None:
        self.items = deque(maxlen=capacity)

    def waiting(self) -> bool:
        return self.latched is not None or bool(self.items)

    def add(self, item: T) -> None:
        """Under the intake's guard: keep ``item`` (see the class docstring for what it supersedes)."""
        items = self.items
        if self.latch is not None and self.latched is None and self.latch(item):
            superseded = len(items)
            items.clear()
            self.latched = item
        else:
            superseded = 1 if len(items) == items.maxlen else 0
            items.append(item)
        self.dropped += superseded
        self.unreported += superseded
        self.received += 1

    def pop(self) -> T | None:
        """Under the intake's guard: the next item to handle (a latched one first), or None."""
        if self.latched is not None:
            item, self.latched = self.latched, None
            return item
        return self.items.popleft() if self.items else None


@dataclass(eq=False)
class Intake:
    """Thread-safe hand-over from Zenoh's threads to one asyncio loop; nothing here relies on the GIL.

    :attr:`guard` is held only to add or pop one item; :attr:`lock` (the core's) is held by drains, and tried,
    never waited for, by a direct take.
    """

    loop: asyncio.AbstractEventLoop
    #: Called with an exception a handler raised (the drain goes on with the next item); None: the loop's handler.
    on_error: Callable[[BaseException], None] | None = None
    #: The core's lock, for a service whose core other threads may drive: drains hold it, direct takes need it.
    lock: CoreLock | None = None
    clock: Callable[[], float] = time.monotonic
    #: Called on the loop after every drain, outside :attr:`lock` (the gateway publishes what the inputs produced).
    after_drain: Callable[[], None] | None = None
    #: Guards the channels' contents and counters and ``_scheduled``; never held while a handler runs.
    guard: threading.Lock = field(default_factory=threading.Lock, init=False)
    _channels: list[Channel[Any]] = field(default_factory=list, init=False)
    _scheduled: bool = field(default=False, init=False)
    #: Closed: nothing is handed over or handled any more (the edge is undeclaring).
    _closed: bool = field(default=False, init=False)
    #: Set after every drain: a pump thread waits on it before it hands over more (see GuardedInput).
    drained: threading.Event = field(default_factory=threading.Event, init=False)

    def channel(
        self,
        name: str,
        handler: Callable[[T], None],
        *,
        capacity: int = 1024,
        latest: bool = False,
        latch: Callable[[T], bool] | None = None,
        priority: int = 0,
        direct: Callable[[T], bool] | None = None,
        on_dropped: Callable[[int], None] | None = None,
    ) -> Callable[[T], None]:
        """A thread-safe ``put`` for ``handler``; ``latest``, ``latch``: see :class:`Channel`.

        ``on_dropped(n)``: on the loop, before the next item, how many were dropped since. ``direct(item)`` takes an
        item in the putting thread under :attr:`lock` (False: it waits for the loop): only while the lock is free,
        nothing of this priority or higher waits, and within DIRECT_BURST per DIRECT_WINDOW_S. It must not block;
        its only Zenoh call may be a put with drop congestion control.
        """
        if direct is not None and self.lock is None:
            raise ValueError(f"channel {name!r}: a direct channel needs the intake's core lock")
        channel: Channel[T] = Channel(name, handler, 1 if latest else capacity, priority, latch, on_dropped)
        self._channels.append(channel)
        self._channels.sort(key=lambda c: -c.priority)
        for each in self._channels:
            each.ahead = [other for other in self._channels if other.priority >= each.priority]
        guard = self.guard

        def put(item: T) -> None:
            if direct is not None and delivering() and self._try_direct(channel, direct, item):
                self.drained.set()  # handled: a pump that put it need not wait for a drain that nothing scheduled
                return
            with guard:
                if self._closed:
                    return
                channel.add(item)
                if self._scheduled:
                    return
                self._scheduled = True
            try:
                self.loop.call_soon_threadsafe(self._drain)
            except RuntimeError:  # the loop is closed: the service is stopping
                pass

        return put

    def _try_direct(self, channel: Channel[T], direct: Callable[[T], bool], item: T) -> bool:
        """The putting thread: ``direct(item)`` under the lock, if the rules of :meth:`channel` allow; whether it was taken."""
        lock = self.lock
        if lock is None or not lock.acquire(blocking=False):
            return False
        try:
            with self.guard:
                if self._closed:
                    return False  # the edge is undeclaring: nothing is handled any more (close() holds the lock)
                now = self.clock()
                if now - channel.window_start > DIRECT_WINDOW_S:
                    channel.window_start, channel.window_direct = now, 0
                if channel.window_direct >= DIRECT_BURST:
                    return False
                for other in channel.ahead:
                    if other.latched is not None or other.items:
                        return False  # older items of this priority, or higher (an e-stop), wait: behind them, in order
                channel.received += 1
                channel.direct_taken += 1
                channel.window_direct += 1
            try:
                taken = direct(item)
            except Exception as exc:  # reported on the loop, as a handler's failure in a drain is
                self._report_soon(exc)
                taken = True
            if not taken:
                with self.guard:
                    channel.received -= 1
                    channel.direct_taken -= 1
            return taken
        finally:
            lock.release()

    def _report_soon(self, exc: BaseException) -> None:
        def report() -> None:
            if self.on_error is None:
                self.loop.call_exception_handler({"message": "an input taken directly failed", "exception": exc})
            else:
                self.on_error(exc)

        try:
            self.loop.call_soon_threadsafe(report)
        except RuntimeError:  # the loop is closed: the service is stopping
            pass

    def _drain(self) -> None:
        """The loop: handle what waits now, the highest-priority channel first after every item.

        A lower channel gets at most what it held when the drain began (a flood refilling it waits for the next
        drain); the top one is served at once. Items are popped and handled under the core lock.
        """
        with self.guard:
            self._scheduled = False
            if self._closed:
                return  # scheduled before the close: its handlers would publish through undeclared entities
        with self.lock if self.lock is not None else contextlib.nullcontext():
            self._serve_channels()
        if self.after_drain is not None:
            self.after_drain()
        self.drained.set()

    def _serve_channels(self) -> None:
        channels = self._channels
        if not channels:
            return
        top = channels[0].priority
        guard = self.guard
        with guard:
            budget = [len(c.items) + (c.latched is not None) for c in channels]
        while True:
            for index, channel in enumerate(channels):
                with guard:
                    if not channel.waiting() or (budget[index] <= 0 and channel.priority != top):
                        continue
                    item = channel.pop()
                    dropped, channel.unreported = channel.unreported, 0
                budget[index] -= 1
                try:
                    if dropped and channel.on_dropped is not None:
                        channel.on_dropped(dropped)
                    channel.handler(item)
                except Exception as exc:
                    if self.on_error is None:
                        raise
                    self.on_error(exc)
                break
            else:
                return

    def close(self) -> None:
        """From now on, hand nothing over and handle nothing: a drain already scheduled on the loop does nothing.

        The edge calls it before it undeclares its entities, so no handler runs against a closed publisher. It takes
        the core's lock, when there is one: a direct take in progress ends first, and none starts after."""
        with self.lock if self.lock is not None else contextlib.nullcontext(), self.guard:
            self._closed = True
            for channel in self._channels:
                channel.items.clear()
                channel.latched = None

    def stats(self) -> dict[str, tuple[int, int]]:
        """Per channel: items received (directly taken ones included) and items dropped because the channel was full."""
        with self.guard:
            return {c.name: (c.received, c.dropped) for c in self._channels}
