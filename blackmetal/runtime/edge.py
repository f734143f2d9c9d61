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
to wake (see :meth:`Intake.channel`). :class:`ZenohEdge` keeps every
declared entity and undeclares them in reverse order of declaration.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from blackmetal.schemas import ConfigError, Keys, any_alive, payload_bytes

from .host import CoreLock
from .inbox import LoopInbox

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
#: A pump hands a batch over at most this often: a flood costs the loop at most 500 hand-overs a second.
PUMP_PERIOD_S = 0.002

Item = tuple[str, bytes]
#: What of a batch a pump hands over (all of it unless said otherwise): a latest-slot input needs only its newest.
Pick = Callable[[list[Item]], list[Item]]


def newest(batch: list[Item]) -> list[Item]:
    """A :data:`Pick` for an input of which only the newest sample counts (a command source, a lock)."""
    return batch[-1:]


#: A channel takes at most DIRECT_BURST items directly within DIRECT_WINDOW_S (200 a second); the rest wait for
#: the loop. Commanders at 10-100 Hz are all taken directly, and a burst cannot keep Zenoh's thread in handlers.
DIRECT_BURST = 20
DIRECT_WINDOW_S = 0.1


class Channel(Generic[T]):
    """One input of a service: items from any thread, handled on the loop in arrival order.

    ``latest``: one slot, a newer item supersedes the waiting one (counted in
    ``dropped``). ``latch(item)`` true marks an item that must be handled even
    when newer ones supersede it (an e-stop ON): the first such item since the
    last take waits in its own slot, is handled first, and drops every older
    item; the newest item still follows it (an OFF newer than the ON).
    """

    def __init__(
        self,
        name: str,
        handler: Callable[[T], None],
        capacity: int,
        priority: int,
        latch: Callable[[T], bool] | None = None,
        on_dropped: Callable[[int], None] | None = None,
    ) -> None:
        self.name = name
        self.handler = handler
        self.priority = priority
        self.latch = latch
        self.on_dropped = on_dropped
        self.items: deque[T] = deque(maxlen=capacity)
        self.latched: T | None = None
        self.dropped = 0
        #: Dropped since the handler was last told (``on_dropped``).
        self.unreported = 0
        self.received = 0
        #: Items taken directly (in the putting thread), and the current window of the direct budget.
        self.direct_taken = 0
        self.window_start = -math.inf
        self.window_direct = 0

    def waiting(self) -> bool:
        return self.latched is not None or bool(self.items)

    def add(self, item: T) -> None:
        """Under the hand-over's lock: keep ``item`` (see the class docstring for what it supersedes)."""
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
        """Under the hand-over's lock: the next item to handle (a latched one first), or None."""
        if self.latched is not None:
            item, self.latched = self.latched, None
            return item
        return self.items.popleft() if self.items else None


class Intake:
    """Thread-safe hand-over from Zenoh's threads to one asyncio loop: the service's one intake.

    Every channel's items, its counters and the "drain scheduled" flag are
    guarded by :attr:`guard`, a plain lock held only to add or pop one item
    (never while a handler runs), so nothing here relies on the GIL. The
    second lock, when given, is the core's (:attr:`lock`): drains hold it
    while they handle items, and a ``direct`` channel's put takes it (never
    waiting for it) to handle an item at once.
    """

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        on_error: Callable[[BaseException], None] | None = None,
        lock: CoreLock | None = None,
        clock: Callable[[], float] = time.monotonic,
        after_drain: Callable[[], None] | None = None,
        inbox: LoopInbox | None = None,
    ) -> None:
        self.loop = loop
        #: The loop's inbox: its busy steps take what waits here early (None: at the end of the loop's turn only).
        self.inbox = inbox
        self.clock = clock
        #: Called with an exception a handler raised (the drain goes on with the next item); None: the loop's handler.
        self.on_error = on_error
        #: The core's lock, for a service whose core other threads may drive: drains hold it, direct takes need it.
        self.lock = lock
        #: Called on the loop after every drain, outside :attr:`lock` (the gateway publishes what the inputs produced).
        self.after_drain = after_drain
        #: Guards the channels' contents and counters, ``_scheduled`` and ``_in_inbox``; never held while a handler runs.
        self.guard = threading.Lock()
        self._channels: list[Channel[Any]] = []
        self._scheduled = False
        self._in_inbox = False
        self._serve_early_ref = weakref.WeakMethod(self._serve_early)
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
        latch: Callable[[T], bool] | None = None,
        priority: int = 0,
        direct: Callable[[T], bool] | None = None,
        on_dropped: Callable[[int], None] | None = None,
    ) -> Callable[[T], None]:
        """A thread-safe ``put`` for ``handler``; ``latest`` keeps only the newest item, ``latch`` see :class:`Channel`.

        ``on_dropped(n)`` is called on the loop, before the next item is
        handled, with how many items were dropped since it was last called.
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
        channel: Channel[T] = Channel(name, handler, 1 if latest else capacity, priority, latch, on_dropped)
        self._channels.append(channel)
        self._channels.sort(key=lambda c: -c.priority)
        guard = self.guard
        inbox = self.inbox

        def put(item: T) -> None:
            if direct is not None and self._try_direct(channel, direct, item):
                self.drained.set()  # handled: a pump that put it need not wait for a drain that nothing scheduled
                return
            with guard:
                channel.add(item)
                if self._scheduled:
                    return
                self._scheduled = True
                early = inbox is not None and not self._in_inbox
                if early:
                    self._in_inbox = True
            if early and inbox is not None:  # the loop's next step of work may take it before the scheduled drain
                inbox.add(self._serve_early_ref)
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
            if self._serving:
                return False  # the loop's own handler put it: it waits for the drain, as it always did
            with self.guard:
                now = self.clock()
                if now - channel.window_start > DIRECT_WINDOW_S:
                    channel.window_start, channel.window_direct = now, 0
                if channel.window_direct >= DIRECT_BURST:
                    return False
                for other in self._channels:  # highest priority first
                    if other.priority < channel.priority:
                        break
                    if other.waiting():
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

    def _serve_early(self) -> None:
        """The loop, between two steps of its own work (:mod:`blackmetal.runtime.inbox`): the top channel, one item of each other.

        The scheduled drain still runs at the end of the loop's turn and takes
        the rest: a flood gets one early item per turn, so it cannot crowd the
        loop's own steps (a flooded robot's commands between every poll of a
        fleet took the other robots from 50 to 30 Hz).
        """
        with self.guard:
            self._in_inbox = False
            scheduled = self._scheduled
        if scheduled and not self._serving:  # never inside a handler of this hand-over
            self._serve(early=True)

    def _drain(self) -> None:
        """Handle the items waiting now, one at a time, the highest-priority channel first after every item.

        Each lower channel is served at most as many items as it held when the
        drain began: a flood that refills it while the drain runs waits for
        the next drain (which its ``put`` schedules), so it can neither keep
        the loop from its timers and sockets nor hold a newer e-stop behind
        it. The top channel is always served at once.
        """
        with self.guard:
            self._scheduled = False
        self._serve(early=False)
        self.drained.set()

    def _serve(self, early: bool) -> None:
        if self.lock is None:
            self._serve_locked(early)
        else:
            with self.lock:  # a direct take must not come between an item's pop and its handling
                self._serve_locked(early)
        if self.after_drain is not None:
            self.after_drain()

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
        guard = self.guard
        with guard:
            budget = [min(len(c.items) + (c.latched is not None), 1 if early else 1 << 30) for c in channels]
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

    def stats(self) -> dict[str, tuple[int, int]]:
        """Per channel: items received (directly taken ones included) and items dropped because the channel was full."""
        with self.guard:
            return {c.name: (c.received, c.dropped) for c in self._channels}


def refuse_taken(
    session: "zenoh.Session",
    role: str,
    prefixes: Sequence[str],
    *,
    what: str | None = None,
    describe: Callable[[str], str] | None = None,
    timeout: float = 0.5,
) -> None:
    """ConfigError naming the first prefix on which another ``role`` (``gateway``, ``odometry``) is alive.

    One liveliness query for any number of prefixes (call before declaring
    our own tokens). ``what`` names the service in the sentence (default
    ``role``), ``describe(prefix)`` the robot of a fleet.
    """
    alive = {
        Keys.prefix_of_token(str(reply.ok.key_expr), role)
        for reply in session.liveliness().get(any_alive(role), timeout=timeout)
        if reply.ok is not None
    }
    for prefix in prefixes:
        if prefix in alive:
            who = f"{describe(prefix)}: " if describe is not None else ""
            fix = "give this robot another prefix" if describe is not None else "give this one another --prefix (e.g. --prefix fleet/b)"
            raise ConfigError(
                f"{who}another {what or role} is already alive on prefix {prefix!r} ({Keys(prefix).alive(role)}); one robot per prefix: "
                f"stop the other one, or {fix}"
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
        """Payload bytes of every sample on ``key`` go to ``put`` (an Intake channel)."""
        self._entities.append(self.session.declare_subscriber(key, lambda sample: put(payload_bytes(sample))))

    def named_subscriber(self, key: str, put: Callable[[tuple[str, bytes]], None]) -> None:
        """``(last key chunk, payload)`` of every sample on ``key`` (e.g. ``robot/cmd_vel/*``) go to ``put``."""

        self._entities.append(self.session.declare_subscriber(key, lambda sample: put(_chunk_and_payload(sample))))

    def guarded(
        self,
        key: str,
        put: Callable[[tuple[str, bytes]], None],
        handover: Intake,
        on_flood: Callable[[str, str], None] | None = None,
        pick: Pick | None = None,
    ) -> "GuardedInput":
        """``(last key chunk, payload)`` of samples on ``key`` go to ``put``; for inputs a client may flood (see :class:`GuardedInput`)."""
        guarded = GuardedInput(self.session, key, put, handover, on_flood, pick=pick)
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
        handover: Intake,
        on_flood: Callable[[str, str], None] | None = None,
        *,
        capacity: int = 64,
        quiet_s: float = QUIET_S,
        pick: Pick | None = None,
    ) -> None:
        """``pick``: what of each batch the pump hands over while the input floods (default: every sample)."""
        self.session = session
        self.pick = pick
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
            if self.handover.inbox is not None:
                self.handover.inbox.add(self._to_ring_ref)  # at the loop's next step, not after its turn
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
                while len(batch) < self.capacity and (more := samples.try_recv()) is not None:
                    batch.append(more)
            except zenoh.ZError:  # "empty and closed": undeclared (the flood is over, or the edge closes)
                return
            if stop.is_set():
                return
            handed = time.monotonic()
            self._last_sample = handed
            items = [self._item(sample) for sample in batch]
            drained.clear()
            for item in items if self.pick is None else self.pick(items):
                self.put(item)
            drained.wait(0.1)
            stop.wait(max(0.0, handed + PUMP_PERIOD_S - time.monotonic()))  # the ring fills meanwhile; only its newest count

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
