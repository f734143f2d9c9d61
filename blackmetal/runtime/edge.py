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
(or a flood) of anything else.
:class:`ZenohEdge` keeps every declared entity and undeclares them in
reverse order of declaration.
"""

from __future__ import annotations

import asyncio
import threading
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from schemas import ConfigError, payload_bytes

if TYPE_CHECKING:
    import zenoh

T = TypeVar("T")

#: How long closing waits for a pump thread to leave Zenoh (it wakes at once when its subscriber goes).
PUMP_JOIN_S = 1.0

#: How long closing waits for a pump thread to leave Zenoh (it wakes at once when its subscriber goes).
PUMP_JOIN_S = 1.0


class Channel(Generic[T]):
    """One input of a service: items from any thread, handled on the loop in arrival order."""

    def __init__(self, name: str, handler: Callable[[T], None], capacity: int, priority: int) -> None:
        self.name = name
        self.handler = handler
        self.priority = priority
        self.items: deque[T] = deque(maxlen=capacity)
        self.dropped = 0
        self.received = 0


class Handover:
    """Thread-safe hand-over from Zenoh's threads to one asyncio loop.

    Lock-free: ``deque.append``/``popleft`` are atomic, and the drain clears
    its "scheduled" flag *before* it empties the channels, so an item that
    arrives while a drain runs is either taken by it or schedules the next
    one; at worst a drain finds nothing to do.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, on_error: Callable[[BaseException], None] | None = None) -> None:
        self.loop = loop
        #: Called with an exception a handler raised (the drain goes on with the next item); None: the loop's handler.
        self.on_error = on_error
        self._channels: list[Channel[Any]] = []
        self._scheduled = False
        #: Set after every drain: a pump thread waits on it before it hands over more (see ZenohEdge.pumped).
        self.drained = threading.Event()

    def channel(
        self, name: str, handler: Callable[[T], None], *, capacity: int = 1024, latest: bool = False, priority: int = 0
    ) -> Callable[[T], None]:
        """A thread-safe ``put`` for ``handler``; ``latest`` keeps only the newest item."""
        channel: Channel[T] = Channel(name, handler, 1 if latest else capacity, priority)
        self._channels.append(channel)
        self._channels.sort(key=lambda c: -c.priority)
        items = channel.items

        def put(item: T) -> None:
            if len(items) == items.maxlen:
                channel.dropped += 1
            items.append(item)
            channel.received += 1
            if not self._scheduled:
                self._scheduled = True
                try:
                    self.loop.call_soon_threadsafe(self._drain)
                except RuntimeError:  # the loop is closed: the service is stopping
                    pass

        return put

    def _drain(self) -> None:
        """Handle the items waiting now, one at a time, the highest-priority channel first after every item.

        Each lower channel is served at most as many items as it held when the
        drain began: a flood that refills it while the drain runs waits for
        the next drain (which its ``put`` schedules), so it can neither keep
        the loop from its timers and sockets nor hold a newer e-stop behind
        it. The top channel is always served at once.
        """
        self._scheduled = False
        channels = self._channels
        if not channels:
            return
        top = channels[0].priority
        budget = [len(channel.items) for channel in channels]
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
                self.drained.set()
                return

    def stats(self) -> dict[str, tuple[int, int]]:
        """Per channel: items received and items dropped because the channel was full."""
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
        self._pumps: list[threading.Thread] = []

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

        def on_sample(sample: "zenoh.Sample") -> None:
            put((str(sample.key_expr).rpartition("/")[2], payload_bytes(sample)))

        self._entities.append(self.session.declare_subscriber(key, on_sample))

    def pumped(self, key: str, put: Callable[[tuple[str, bytes]], None], handover: Handover, capacity: int = 64) -> None:
        """``(last key chunk, payload)`` of samples on ``key`` go to ``put`` at the pace the loop takes them; for inputs that may flood.

        The samples wait in Zenoh's own ring buffer (``capacity`` newest, the
        oldest dropped without touching Python), and one thread moves what is
        there to ``put`` and waits for the loop's next drain before it takes
        more. A flood then costs Python the loop's own pace, not one callback
        per sample: the GIL stays free for the e-stop's callback, the robot
        link and the timers.
        """
        import zenoh

        subscriber = self.session.declare_subscriber(key, zenoh.handlers.RingChannel(capacity))
        self._entities.append(subscriber)
        # Wait on the handler, not the subscriber: a thread blocked in
        # ``subscriber.recv()`` holds the subscriber borrowed, so ``undeclare()``
        # fails ("Already borrowed") and the pump never wakes.
        samples = subscriber.handler

        def pump() -> None:
            while True:
                try:
                    batch = [samples.recv()]  # blocks without the GIL
                    while (more := samples.try_recv()) is not None:
                        batch.append(more)
                except zenoh.ZError:  # "empty and closed": undeclared, the edge is closing
                    return
                handover.drained.clear()
                for sample in batch:
                    put((str(sample.key_expr).rpartition("/")[2], payload_bytes(sample)))
                handover.drained.wait(0.1)

        thread = threading.Thread(target=pump, name=f"pump {key}", daemon=True)
        thread.start()
        self._pumps.append(thread)

    def queryable(self, key: str, put: Callable[["zenoh.Query"], None]) -> None:
        """Every query on ``key`` goes to ``put``; the handler answers it on the loop (``with query: ...``)."""
        self._entities.append(self.session.declare_queryable(key, put))

    def token(self, key: str) -> None:
        """A liveliness token, present while this edge is open."""
        self._entities.append(self.session.liveliness().declare_token(key))

    def close(self) -> None:
        import zenoh

        for entity in reversed(self._entities):
            try:
                entity.undeclare()
            except zenoh.ZError:  # already undeclared by a closing session
                pass
        self._entities.clear()
        # The pumps wake as their subscribers go; each must be out of Zenoh before the
        # interpreter finalizes, or CPython ends it mid-unwind and the process aborts
        # ("FATAL: exception not rethrown").
        for thread in self._pumps:
            thread.join(PUMP_JOIN_S)
        self._pumps.clear()
        # A pump woken by the undeclare must be out of Zenoh before the interpreter
        # finalizes: a thread that takes the GIL back inside Zenoh's frames then is
        # ended by CPython mid-unwind, and the process aborts ("FATAL: exception not rethrown").
        for thread in self._pumps:
            thread.join(PUMP_JOIN_S)
        self._pumps.clear()
