"""Inputs a client may flood: Python callbacks at sane rates, Zenoh's ring buffer and one pump thread while it floods.

See :class:`GuardedInput`. The pump hands what it takes to the service's
:class:`~blackmetal.runtime.intake.Intake` like a callback does, so the
intake's bounds and priorities hold whichever way a sample came.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from collections.abc import Callable
from dataclasses import KW_ONLY, dataclass, field
from typing import TYPE_CHECKING, Any

from blackmetal.schemas import payload_bytes

from .driver import queue_only
from .intake import Intake
from .zenoh_entities import chunk_and_payload, undeclare

if TYPE_CHECKING:
    import zenoh

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

#: What of a batch a pump hands over (all of it unless said otherwise): a latest-slot input needs only its newest.
Pick = Callable[[list[Any]], list[Any]]


def newest(batch: list[Any]) -> list[Any]:
    """A :data:`Pick` for an input of which only the newest sample counts (a command source, a lock)."""
    return batch[-1:]


@dataclass(eq=False)
class GuardedInput:
    """An input that a client may flood: Python callbacks at sane rates, Zenoh's ring buffer while it floods.

    Zenoh runs callbacks on the thread that reads the link, so a key flooded
    at full speed would hold every other sample of the link (another robot's
    e-stop) behind it. Beyond FLOOD_SAMPLES within FLOOD_WINDOW_S the key
    changes over to a ring-buffered subscriber (the ``capacity`` newest kept,
    without Python) and one pump thread that hands them to ``put`` at the
    loop's pace; after QUIET_S without a sample it changes back (an idle pump
    is not free: zenoh-python wakes a blocked ``recv`` ten times a second,
    GIL and all). The loop makes the changes and tells ``on_flood(key,
    reason)``; the new subscriber is declared before the old one goes, so no
    sample is lost (one may arrive twice).
    """

    session: "zenoh.Session"
    key: str
    put: Callable[[Any], None]
    intake: Intake
    on_flood: Callable[[str, str], None] | None = None
    _: KW_ONLY
    capacity: int = 64
    quiet_s: float = QUIET_S
    #: What of each batch the pump hands over while the input floods (default: every sample).
    pick: Pick | None = None
    #: A sample becomes the item ``(name, payload)``: ``name`` is the key's last chunk unless given (``cmd_vel`` is the
    #: source ``default``); with ``decode``, the item is ``decode(payload)`` instead, decoded once, where it enters.
    name: str | None = None
    decode: Callable[[bytes], Any] | None = None
    #: Samples whose last chunk is one of these (names another input takes) are not handed over.
    skip: frozenset[str] = frozenset()
    #: False: the callback runs on the thread that reads the link, one thread wake fewer (docs/performance.md).
    indirect: bool = True
    _subscriber: Any = field(default=None, init=False)
    _pump: threading.Thread | None = field(default=None, init=False)
    #: Guards the flood count and ``_changing``: Zenoh may call one subscriber's callback on several threads (one per link).
    _count_lock: threading.Lock = field(default_factory=threading.Lock, init=False)
    _window_start: float = field(default=-math.inf, init=False)
    _window_count: int = field(default=0, init=False)
    _changing: bool = field(default=False, init=False)
    _last_sample: float = field(default=0.0, init=False)
    _quiet_check: asyncio.TimerHandle | None = field(default=None, init=False)
    _closed: bool = field(default=False, init=False)
    #: Set by Zenoh once the callback subscriber is gone and its queued samples are all handed over.
    _callback_gone: threading.Event = field(default_factory=threading.Event, init=False)
    #: Tells the pump to end (its subscriber is going).
    _pump_stop: threading.Event = field(default_factory=threading.Event, init=False)

    def __post_init__(self) -> None:
        #: A key without wildcards has one last chunk: no key expression to turn into text per sample.
        self._chunk = self.name or (None if "*" in self.key else self.key.rpartition("/")[2])

    def _item(self, sample: "zenoh.Sample") -> Any:
        if self.decode is not None:
            return self.decode(payload_bytes(sample))
        return chunk_and_payload(sample) if self._chunk is None else (self._chunk, payload_bytes(sample))

    @property
    def flooded(self) -> bool:
        """Whether samples now come through the ring buffer and a pump thread."""
        return self._pump is not None

    def start(self) -> None:
        import zenoh

        gone = self._callback_gone = threading.Event()
        self._subscriber = self.session.declare_subscriber(
            self.key, zenoh.handlers.Callback(self._on_sample, drop=gone.set, indirect=self.indirect)
        )

    def _on_sample(self, sample: "zenoh.Sample") -> None:
        """Zenoh's thread: hand the sample over, and count it against the flood limit."""
        item = self._item(sample)
        if not self.skip or item[0] not in self.skip:
            self.put(item)
        now = time.monotonic()
        with self._count_lock:
            if now - self._window_start > FLOOD_WINDOW_S:
                self._window_start, self._window_count = now, 0
            self._window_count += 1
            change = self._window_count > FLOOD_SAMPLES and not self._changing
            self._changing = self._changing or change
        if change:
            try:
                self.intake.loop.call_soon_threadsafe(self._to_ring)
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
            with self._count_lock:
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
        undeclare(callback)
        self._quiet_check = self.intake.loop.call_later(self.quiet_s / 2, self._check_quiet)
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

        queue_only()  # the direct-take rule: a pump never runs the core, it only queues
        drained = self.intake.drained
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
            items = [item for item in map(self._item, batch) if not self.skip or item[0] not in self.skip]
            if not items:
                continue
            drained.clear()
            for item in items if self.pick is None else self.pick(items):
                self.put(item)
            drained.wait(0.1)
            stop.wait(max(0.0, handed + PUMP_PERIOD_S - time.monotonic()))  # the ring fills meanwhile; only its newest count

    def _end_pump(self, subscriber: Any) -> None:
        """The loop: undeclare ``subscriber`` and end the pump, without waiting out its wait for a drain (only the loop ends that)."""
        pump, self._pump = self._pump, None
        self._pump_stop.set()
        self.intake.drained.set()
        if subscriber is not None:
            undeclare(subscriber)
        if pump is not None:
            pump.join(PUMP_JOIN_S)

    def _check_quiet(self) -> None:
        """The loop: after ``quiet_s`` without a sample, back to a callback (the pump ends with its subscriber)."""
        self._quiet_check = None
        if self._closed or self._pump is None:
            return
        if time.monotonic() - self._last_sample < self.quiet_s:
            self._quiet_check = self.intake.loop.call_later(self.quiet_s / 2, self._check_quiet)
            return
        ring = self._subscriber
        with self._count_lock:
            self._window_start, self._window_count, self._changing = -math.inf, 0, False
        try:
            self.start()
        except Exception:  # the ring stays until a callback can be declared
            self._quiet_check = self.intake.loop.call_later(self.quiet_s / 2, self._check_quiet)
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
