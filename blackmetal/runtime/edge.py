"""The one way a service meets Zenoh: declare at the edge, hand every sample over to the service's loop.

Zenoh calls back on its own threads. A callback here only copies the
payload and appends it to a bounded channel, then wakes the service's
asyncio loop once per batch; the service's handlers run on that loop, never
inside a Zenoh callback, and never block Zenoh. Channels are bounded: a
``latest`` channel keeps only the newest item (a newer command supersedes an
older one), a queue keeps at most ``capacity`` items and drops the oldest,
counting what it dropped. Channels with a higher ``priority`` are drained
first and looked at again after every item, and a drain takes no more than
was waiting when it began, so an emergency stop is handled before a backlog
(or a flood) of anything else. A busy loop takes waiting inputs between
two steps of its own work (:mod:`blackmetal.runtime.inbox`). A channel
may also be taken ``direct``: in the putting thread, under the core's lock,
when the core is free and nothing of its priority or higher waits; the
gateway sends a command to the robot that way without waiting for its loop
to wake (see :meth:`Handover.channel`). :class:`ZenohEdge` keeps every
declared entity and undeclares them in reverse order of declaration.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from schemas import ConfigError, payload_bytes

from .inbox import inbox_of

if TYPE_CHECKING:
    import zenoh

T = TypeVar("T")

#: How long closing waits for a pump thread to leave Zenoh (it wakes at once when its subscriber goes).
PUMP_JOIN_S = 1.0

#: More than FLOOD_SAMPLES on one guarded key within FLOOD_WINDOW_S (2,000 a second) is a flood: twenty
#: commanders at 100 Hz stay under it, a publisher in a tight loop is over it within milliseconds.
FLOOD_SAMPLES = 200
FLOOD_WINDOW_S = 0.1
#: A flooded key goes back to callbacks after this long without a sample.
QUIET_S = 2.0
#: How long a new pump waits for the old callback to hand over what it had queued before it hands over anything.
CALLBACK_GONE_S = 1.0
#: A channel takes at most DIRECT_BURST items directly within DIRECT_WINDOW_S (200 a second); the rest wait for
#: the loop. Commanders at 10-100 Hz are all taken directly, and a burst cannot keep Zenoh's thread in handlers.
DIRECT_BURST = 20
DIRECT_WINDOW_S = 0.1


class Channel(Generic[T]):
    """One input of a service: items from any thread, handled on the loop in arrival order."""

    def __init__(self, name: str, handler: Callable[[T], None], capacity: int, priority: int) -> None:
        self.name = name
        self.handler = handler
        self.priority = priority
        self.items: deque[T] = deque(maxlen=capacity)
        self.dropped = 0
        self.received = 0
        #: Items taken directly (in the putting thread), and the current window of the direct budget.
        self.direct_taken = 0
        self.window_start = -math.inf
        self.window_direct = 0


class Handover:
    """Thread-safe hand-over from Zenoh's threads to one asyncio loop.

    The channels are lock-free: ``deque.append``/``popleft`` are atomic, and
    the drain clears its "scheduled" flag *before* it empties the channels,
    so an item that arrives while a drain runs is either taken by it or
    schedules the next one; at worst a drain finds nothing to do. The one
    lock, when given, is the core's: drains hold it, and a ``direct``
    channel's put takes it (never waiting for it) to handle an item at once.
    """

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        on_error: Callable[[BaseException], None] | None = None,
        lock: threading.RLock | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.loop = loop
        self.clock = clock
        #: Called with an exception a handler raised (the drain goes on with the next item); None: the loop's handler.
        self.on_error = on_error
        #: The core's lock, for a service whose core other threads may drive: drains hold it, direct takes need it.
        self.lock = lock
        self._channels: list[Channel[Any]] = []
        self._scheduled = False
        self._inbox = inbox_of(loop)
        self._in_inbox = False
        self._take_early_ref = weakref.WeakMethod(self._take_early)
        self._serving = False
        #: Set after every drain: a pump thread waits on it before it hands over more (see GuardedInput).
        self.drained = threading.Event()

    def channel(
        self,
        name: str,
        handler: Callable[[T], None],
        *,
        capacity: int = 1024,
        latest: bool = False,
        priority: int = 0,
        direct: Callable[[T], bool] | None = None,
    ) -> Callable[[T], None]:
        """A thread-safe ``put`` for ``handler``; ``latest`` keeps only the newest item.

        ``direct(item)`` takes an item in the thread that puts it, under
        :attr:`lock`, and says whether it did (False: it waits for the loop as
        any other). It is tried only while the lock is free (the loop is not
        in the core), nothing of this priority or higher waits (order is
        kept: a drain pops and handles under the lock), and the channel is
        within its direct budget (DIRECT_BURST per DIRECT_WINDOW_S). It must
        not block, call Zenoh or touch the loop except by ``call_soon_threadsafe``.
        """
        if direct is not None and self.lock is None:
            raise ValueError(f"channel {name!r}: a direct channel needs the hand-over's lock")
        channel: Channel[T] = Channel(name, handler, 1 if latest else capacity, priority)
        self._channels.append(channel)
        self._channels.sort(key=lambda c: -c.priority)
        items = channel.items

        def put(item: T) -> None:
            if direct is not None and self._take_direct(channel, direct, item):
                return
            if len(items) == items.maxlen:
                channel.dropped += 1
            items.append(item)
            channel.received += 1
            if not self._scheduled:
                self._scheduled = True
                if not self._in_inbox:  # the loop's next step of work may take it before the scheduled drain
                    self._in_inbox = True
                    self._inbox.add(self._take_early_ref)
                try:
                    self.loop.call_soon_threadsafe(self._drain)
                except RuntimeError:  # the loop is closed: the service is stopping
                    pass

        return put

    def _take_direct(self, channel: Channel[T], direct: Callable[[T], bool], item: T) -> bool:
        """The putting thread: ``direct(item)`` under the lock, if the rules of :meth:`channel` allow; whether it was taken."""
        lock = self.lock
        if lock is None or not lock.acquire(blocking=False):
            return False
        try:
            now = self.clock()
            if now - channel.window_start > DIRECT_WINDOW_S:
                channel.window_start, channel.window_direct = now, 0
            if channel.window_direct >= DIRECT_BURST:
                return False
            if self._serving:
                return False  # the loop's own handler put it: it waits for the drain, as it always did
            for other in self._channels:  # highest priority first
                if other.priority < channel.priority:
                    break
                if other.items:
                    return False  # older items of this priority, or higher, wait: behind them, in order
            try:
                taken = direct(item)
            except Exception as exc:  # reported on the loop, as a handler's failure in a drain is
                self._report_soon(exc)
                taken = True
            if taken:
                channel.received += 1
                channel.direct_taken += 1
                channel.window_direct += 1
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

    def _take_early(self) -> None:
        """The loop, between two steps of its own work (:mod:`blackmetal.runtime.inbox`): the top channel, one item of each other.

        The scheduled drain still runs at the end of the loop's turn and takes
        the rest: a flood gets one early item per turn, so it cannot crowd the
        loop's own steps (a flooded robot's commands between every poll of a
        fleet took the other robots from 50 to 30 Hz).
        """
        self._in_inbox = False
        if self._scheduled and not self._serving:  # never inside a handler of this hand-over
            self._serve(early=True)

    def _drain(self) -> None:
        """Handle the items waiting now, one at a time, the highest-priority channel first after every item.

        Each lower channel is served at most as many items as it held when the
        drain began: a flood that refills it while the drain runs waits for
        the next drain (which its ``put`` schedules), so it can neither keep
        the loop from its timers and sockets nor hold a newer e-stop behind
        it. The top channel is always served at once.
        """
        self._scheduled = False
        self._serve(early=False)
        self.drained.set()

    def _serve(self, early: bool) -> None:
        if self.lock is None:
            self._serve_locked(early)
            return
        with self.lock:  # a direct take must not come between an item's pop and its handling
            self._serve_locked(early)

    def _serve_locked(self, early: bool) -> None:
        self._serving = True
        try:
            self._serve_channels(early)
        finally:
            self._serving = False

    def _serve_channels(self, early: bool) -> None:
        channels = self._channels
        if not channels:
            return
        top = channels[0].priority
        budget = [min(len(channel.items), 1) if early else len(channel.items) for channel in channels]
        while True:
            for index, channel in enumerate(channels):
                if channel.items and (budget[index] > 0 or channel.priority == top):
                    try:
                        item = channel.items.popleft()
                    except IndexError:
                        continue
                    budget[index] -= 1
                    try:
                        channel.handler(item)
                    except Exception as exc:
                        if self.on_error is None:
                            raise
                        self.on_error(exc)
                    break
            else:
                return

    def stats(self) -> dict[str, tuple[int, int]]:
        """Per channel: items received (directly taken ones included) and items dropped because the channel was full."""
        return {c.name: (c.received, c.dropped) for c in self._channels}


def refuse_if_taken(session: "zenoh.Session", token: str, role: str, prefix: str, timeout: float = 0.5) -> None:
    """ConfigError if another process already holds the liveliness ``token`` (call before declaring ours)."""
    others = [r for r in session.liveliness().get(token, timeout=timeout) if r.ok is not None]
    if others:
        raise ConfigError(
            f"another {role} is already alive on prefix {prefix!r} ({token}); one robot per prefix: "
            f"stop the other one, or give this one another --prefix (e.g. --prefix fleet/b)"
        )


class ZenohEdge:
    """Declares a service's Zenoh entities on an open session and undeclares them, newest first."""

    def __init__(self, session: "zenoh.Session") -> None:
        self.session = session
        self._entities: list[Any] = []
        self._guarded: list[GuardedInput] = []

    def publisher(self, key: str, *, express: bool = False, drop_when_congested: bool = False) -> "zenoh.Publisher":
        import zenoh

        publisher = self.session.declare_publisher(
            key,
            encoding=zenoh.Encoding.APPLICATION_JSON,
            express=express,
            congestion_control=zenoh.CongestionControl.DROP if drop_when_congested else zenoh.CongestionControl.BLOCK,
        )
        self._entities.append(publisher)
        return publisher

    def subscriber(self, key: str, put: Callable[[bytes], None]) -> None:
        """Payload bytes of every sample on ``key`` go to ``put`` (a Handover channel)."""
        self._entities.append(self.session.declare_subscriber(key, lambda sample: put(payload_bytes(sample))))

    def named_subscriber(self, key: str, put: Callable[[tuple[str, bytes]], None]) -> None:
        """``(last key chunk, payload)`` of every sample on ``key`` (e.g. ``robot/cmd_vel/*``) go to ``put``."""

        self._entities.append(self.session.declare_subscriber(key, lambda sample: put(_chunk_and_payload(sample))))

    def guarded(
        self,
        key: str,
        put: Callable[[tuple[str, bytes]], None],
        handover: Handover,
        on_flood: Callable[[str, str], None] | None = None,
    ) -> "GuardedInput":
        """``(last key chunk, payload)`` of samples on ``key`` go to ``put``; for inputs a client may flood (see :class:`GuardedInput`)."""
        guarded = GuardedInput(self.session, key, put, handover, on_flood)
        guarded.start()
        self._guarded.append(guarded)
        return guarded

    def queryable(self, key: str, put: Callable[["zenoh.Query"], None]) -> None:
        """Every query on ``key`` goes to ``put``; the handler answers it on the loop (``with query: ...``)."""
        self._entities.append(self.session.declare_queryable(key, put))

    def token(self, key: str) -> None:
        """A liveliness token, present while this edge is open."""
        self._entities.append(self.session.liveliness().declare_token(key))

    def close(self) -> None:
        for guarded in reversed(self._guarded):
            guarded.close()
        self._guarded.clear()
        for entity in reversed(self._entities):
            _undeclare(entity)
        self._entities.clear()


def _chunk_and_payload(sample: "zenoh.Sample") -> tuple[str, bytes]:
    return str(sample.key_expr).rpartition("/")[2], payload_bytes(sample)


def _undeclare(entity: Any) -> None:
    import zenoh

    try:
        entity.undeclare()
    except zenoh.ZError:  # already undeclared by a closing session
        pass


class GuardedInput:
    """An input that a client may flood: Python callbacks at sane rates, Zenoh's ring buffer while it floods.

    A Python callback per sample is the quickest way in (no thread between
    Zenoh and the loop), but Zenoh runs callbacks on the thread that reads
    the link: a publisher flooding one key at full speed keeps that thread
    in Python, and every other sample on the link (another robot's e-stop)
    waits behind the flood. So a key that delivers more than FLOOD_SAMPLES
    within FLOOD_WINDOW_S changes over to a subscriber with Zenoh's own ring
    buffer (the ``capacity`` newest samples kept, the oldest dropped without
    touching Python) and one pump thread that moves what is there to
    ``put`` at the loop's pace (it waits for the loop's next drain before it
    takes more). After QUIET_S without a sample it changes back: an idle
    pump is not free (zenoh-python wakes a blocked ``recv`` ten times a
    second to look for signals, and each wake takes the GIL from the loop),
    which a fleet of 100 robots with two pumps each paid in command latency.

    The changes are made on the loop, never in a callback, and
    ``on_flood(key, reason)`` is told of each there. The new subscriber is
    declared before the old one goes, so no sample is lost in between (one
    may arrive twice, and samples still queued for an indirect callback's
    thread may come after the first ones through the ring: within a flood,
    whose next sample supersedes them).
    """

    def __init__(
        self,
        session: "zenoh.Session",
        key: str,
        put: Callable[[tuple[str, bytes]], None],
        handover: Handover,
        on_flood: Callable[[str, str], None] | None = None,
        *,
        capacity: int = 64,
        quiet_s: float = QUIET_S,
    ) -> None:
        self.session = session
        self.key = key
        self.put = put
        self.handover = handover
        self.on_flood = on_flood
        self.capacity = capacity
        self.quiet_s = quiet_s
        self._subscriber: Any = None
        self._pump: threading.Thread | None = None
        self._window_start = -math.inf
        self._window_count = 0
        self._changing = False
        self._last_sample = 0.0
        self._quiet_check: asyncio.TimerHandle | None = None
        self._closed = False
        #: Set by Zenoh once the callback subscriber is gone and its queued samples are all handed over.
        self._callback_gone = threading.Event()
        #: Tells the pump to end (its subscriber is going).
        self._pump_stop = threading.Event()
        self._to_ring_ref = weakref.WeakMethod(self._to_ring)
        #: A key without wildcards has one last chunk: no key expression to turn into text per sample.
        self._chunk = None if "*" in key else key.rpartition("/")[2]

    def _item(self, sample: "zenoh.Sample") -> tuple[str, bytes]:
        return _chunk_and_payload(sample) if self._chunk is None else (self._chunk, payload_bytes(sample))

    @property
    def flooded(self) -> bool:
        """Whether samples now come through the ring buffer and a pump thread."""
        return self._pump is not None

    def start(self) -> None:
        import zenoh

        gone = self._callback_gone = threading.Event()
        self._subscriber = self.session.declare_subscriber(self.key, zenoh.handlers.Callback(self._on_sample, drop=gone.set))

    def _on_sample(self, sample: "zenoh.Sample") -> None:
        """Zenoh's thread: hand the sample over, and count it against the flood limit."""
        self.put(self._item(sample))
        now = time.monotonic()
        if now - self._window_start > FLOOD_WINDOW_S:
            self._window_start, self._window_count = now, 0
        self._window_count += 1
        if self._window_count > FLOOD_SAMPLES and not self._changing:
            self._changing = True
            inbox_of(self.handover.loop).add(self._to_ring_ref)  # at the loop's next step, not after its turn
            try:
                self.handover.loop.call_soon_threadsafe(self._to_ring)
            except RuntimeError:  # the loop is closed: the service is stopping
                pass

    def _to_ring(self) -> None:
        """The loop: declare the ring-buffered subscriber and its pump, then undeclare the callback's."""
        import zenoh

        if self._closed or self._pump is not None:
            return
        try:
            ring = self.session.declare_subscriber(self.key, zenoh.handlers.RingChannel(self.capacity))
        finally:
            self._changing = False  # a failure leaves the callback in place, and the next flood tries again
        callback, self._subscriber = self._subscriber, ring
        self._last_sample = time.monotonic()
        self._pump_stop = threading.Event()
        # The pump waits on the handler, not the subscriber: a thread blocked in ``subscriber.recv()``
        # holds the subscriber borrowed, so ``undeclare()`` would fail ("Already borrowed").
        self._pump = threading.Thread(
            target=self._run_pump,
            args=(ring.handler, self._callback_gone, self._pump_stop),
            name=f"pump {self.key}",
            daemon=True,
        )
        self._pump.start()
        _undeclare(callback)
        self._quiet_check = self.handover.loop.call_later(self.quiet_s / 2, self._check_quiet)
        if self.on_flood is not None:
            self.on_flood(
                self.key,
                f"more than {FLOOD_SAMPLES / FLOOD_WINDOW_S:.0f} samples/s on {self.key}: a publisher floods it; until it has "
                f"been quiet for {self.quiet_s:g} s only the newest of each burst are taken (a commander needs 10-100 Hz: "
                "check the publisher's loop)",
            )

    def _run_pump(self, samples: Any, callback_gone: threading.Event, stop: threading.Event) -> None:
        """The pump thread: move what the ring holds to ``put``, then wait for the loop's next drain.

        It hands nothing over before the old callback has handed over all it
        had queued: an older command must not come after a newer one (a flood
        that ends on a stop would otherwise end on whatever came before it).
        """
        import zenoh

        drained = self.handover.drained
        callback_gone.wait(CALLBACK_GONE_S)
        while not stop.is_set():
            try:
                batch = [samples.recv()]  # blocks without the GIL
                while (more := samples.try_recv()) is not None:
                    batch.append(more)
            except zenoh.ZError:  # "empty and closed": undeclared (the flood is over, or the edge closes)
                return
            if stop.is_set():
                return
            self._last_sample = time.monotonic()
            drained.clear()
            for sample in batch:
                self.put(self._item(sample))
            drained.wait(0.1)

    def _end_pump(self, subscriber: Any) -> None:
        """The loop: undeclare ``subscriber`` and end the pump, without waiting out its wait for a drain (only the loop ends that)."""
        pump, self._pump = self._pump, None
        self._pump_stop.set()
        self.handover.drained.set()
        if subscriber is not None:
            _undeclare(subscriber)
        if pump is not None:
            pump.join(PUMP_JOIN_S)

    def _check_quiet(self) -> None:
        """The loop: after ``quiet_s`` without a sample, back to a callback (the pump ends with its subscriber)."""
        self._quiet_check = None
        if self._closed or self._pump is None:
            return
        if time.monotonic() - self._last_sample < self.quiet_s:
            self._quiet_check = self.handover.loop.call_later(self.quiet_s / 2, self._check_quiet)
            return
        ring = self._subscriber
        self._window_start, self._window_count, self._changing = -math.inf, 0, False
        try:
            self.start()
        except Exception:  # the ring stays until a callback can be declared
            self._quiet_check = self.handover.loop.call_later(self.quiet_s / 2, self._check_quiet)
            raise
        self._end_pump(ring)
        if self.on_flood is not None:
            self.on_flood(self.key, f"the flood on {self.key} is over: every sample is taken again")

    def close(self) -> None:
        """Undeclare; a pump wakes as its subscriber goes and is joined.

        It must be out of Zenoh before the interpreter finalizes, or CPython
        ends it mid-unwind and the process aborts ("FATAL: exception not rethrown").
        """
        self._closed = True
        if self._quiet_check is not None:
            self._quiet_check.cancel()
            self._quiet_check = None
        subscriber, self._subscriber = self._subscriber, None
        self._end_pump(subscriber)
