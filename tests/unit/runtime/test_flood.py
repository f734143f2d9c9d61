"""A guarded input's rules, on a fake clock and a fake session: when a key counts as flooded, the change-over and back, close.

The change-over against real Zenoh (samples through the ring buffer, nothing
lost at either change, pumps ending at close) is in tests/unit/runtime/test_edge.py.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from types import SimpleNamespace
from typing import Any

import pytest
import zenoh

from blackmetal.runtime import flood
from blackmetal.runtime.flood import FLOOD_SAMPLES, FLOOD_WINDOW_S, QUIET_S, GuardedInput, newest

KEY = "robot/cmd_vel/nav"


class Handler:
    """A ring buffer's handler that never holds a sample: ``recv`` blocks until the subscriber goes, as Zenoh's does."""

    def __init__(self) -> None:
        self.closed = threading.Event()

    def recv(self) -> Any:
        self.closed.wait()
        raise zenoh.ZError("empty and closed")

    def try_recv(self) -> Any:
        return None


class Subscriber:
    def __init__(self, handler: Any) -> None:
        self.ring = isinstance(handler, zenoh.handlers.RingChannel)
        self.callback = None if self.ring else handler
        self.handler = Handler() if self.ring else None
        self.declared = True

    def undeclare(self) -> None:
        self.declared = False
        if self.handler is not None:
            self.handler.closed.set()
        if self.callback is not None:
            self.callback.drop()  # Zenoh calls drop once the callback has handed over what it had queued


class Session:
    """Records what is declared; ``refuse_rings`` makes declaring a ring buffer fail."""

    def __init__(self) -> None:
        self.subscribers: list[Subscriber] = []
        self.refuse_rings = False

    def declare_subscriber(self, key: str, handler: Any) -> Subscriber:
        assert key == KEY
        if self.refuse_rings and isinstance(handler, zenoh.handlers.RingChannel):
            raise zenoh.ZError("no more subscribers")
        self.subscribers.append(Subscriber(handler))
        return self.subscribers[-1]

    def declared(self) -> list[str]:
        return ["ring" if s.ring else "callback" for s in self.subscribers if s.declared]


class Loop:
    """The loop a guarded input asks for changes: it only records them, the test runs them."""

    def __init__(self) -> None:
        self.soon: list[Callable[[], None]] = []
        self.later: list[tuple[float, Callable[[], None]]] = []
        self.closed = False

    def call_soon_threadsafe(self, callback: Callable[[], None]) -> None:
        if self.closed:
            raise RuntimeError("Event loop is closed")
        self.soon.append(callback)

    def call_later(self, delay: float, callback: Callable[[], None]) -> Any:
        self.later.append((delay, callback))
        return SimpleNamespace(cancel=lambda: self.later.remove((delay, callback)) if (delay, callback) in self.later else None)


def sample(payload: bytes) -> Any:
    return SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: payload))


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> SimpleNamespace:
    """What ``time.monotonic`` says inside the flood module: ``clock.now``."""
    fake = SimpleNamespace(now=1000.0)
    monkeypatch.setattr(flood, "time", SimpleNamespace(monotonic=lambda: fake.now))
    return fake


class Rig:
    def __init__(self) -> None:
        self.session = Session()
        self.loop = Loop()
        self.intake = SimpleNamespace(loop=self.loop, drained=threading.Event())
        self.received: list[tuple[str, bytes]] = []
        self.reports: list[tuple[str, str]] = []
        self.guarded = GuardedInput(
            self.session,  # type: ignore[arg-type]
            KEY,
            self.received.append,
            self.intake,  # type: ignore[arg-type]
            lambda key, reason: self.reports.append((key, reason)),
        )
        self.guarded.start()

    def put(self, count: int, clock: SimpleNamespace, spacing_s: float = 0.0) -> None:
        for i in range(count):
            self.guarded._on_sample(sample(f"{i}".encode()))
            clock.now += spacing_s

    def run_soon(self) -> None:
        """The loop's turn: what the callbacks asked for."""
        soon, self.loop.soon = self.loop.soon, []
        for callback in soon:
            callback()


@pytest.fixture
def rig(clock: SimpleNamespace) -> Iterator[Rig]:
    made = Rig()
    yield made
    made.guarded.close()


def test_newest_keeps_only_the_last_sample_of_a_batch() -> None:
    assert newest([("nav", b"1"), ("nav", b"2"), ("nav", b"3")]) == [("nav", b"3")]
    assert newest([]) == []


def test_up_to_flood_samples_in_a_window_stay_on_the_callback(rig: Rig, clock: SimpleNamespace) -> None:
    """Twenty commanders at 100 Hz are no flood: every sample is handed over at once, nothing changes."""
    rig.put(FLOOD_SAMPLES, clock)
    assert len(rig.received) == FLOOD_SAMPLES and rig.received[0] == ("nav", b"0")
    assert rig.loop.soon == [] and not rig.guarded.flooded
    # the same rate, window after window, never adds up to a flood
    for _ in range(5):
        clock.now += FLOOD_WINDOW_S * 1.01
        rig.put(FLOOD_SAMPLES, clock)
    assert rig.loop.soon == [] and rig.session.declared() == ["callback"]


def test_one_sample_over_the_limit_asks_the_loop_once_for_the_change(rig: Rig, clock: SimpleNamespace) -> None:
    """The change is made on the loop, never in Zenoh's callback; however long the flood, it is asked for once."""
    rig.put(FLOOD_SAMPLES + 1, clock)
    assert len(rig.loop.soon) == 1 and not rig.guarded.flooded
    rig.put(10 * FLOOD_SAMPLES, clock)
    assert len(rig.loop.soon) == 1
    assert len(rig.received) == 11 * FLOOD_SAMPLES + 1, "every sample of a flood is still handed over until the change"


def test_the_change_declares_the_ring_before_the_callback_goes_and_says_why(rig: Rig, clock: SimpleNamespace) -> None:
    rig.put(FLOOD_SAMPLES + 1, clock)
    rig.run_soon()
    assert rig.guarded.flooded and rig.session.declared() == ["ring"]
    assert [t.name for t in threading.enumerate() if t.name == f"pump {KEY}"] == [f"pump {KEY}"]
    assert rig.reports == [
        (
            KEY,
            f"more than 2000 samples/s on {KEY}: a publisher floods it; until it has been quiet for {QUIET_S:g} s only the newest "
            "of each burst are taken (a commander needs 10-100 Hz: check the publisher's loop)",
        )
    ]
    assert [delay for delay, _ in rig.loop.later] == [QUIET_S / 2]  # the first look for quiet


def test_after_quiet_s_without_a_sample_it_goes_back_to_a_callback(rig: Rig, clock: SimpleNamespace) -> None:
    rig.put(FLOOD_SAMPLES + 1, clock)
    rig.run_soon()
    clock.now += QUIET_S / 2
    rig.loop.later.pop()[1]()  # not quiet long enough: look again later
    assert rig.guarded.flooded and len(rig.loop.later) == 1 and len(rig.reports) == 1
    clock.now += QUIET_S / 2
    rig.loop.later.pop()[1]()
    assert not rig.guarded.flooded and rig.session.declared() == ["callback"]
    assert rig.reports[-1] == (KEY, f"the flood on {KEY} is over: every sample is taken again")
    assert not [t for t in threading.enumerate() if t.name == f"pump {KEY}"]
    # the count starts afresh: a flood again is changed over again
    rig.put(FLOOD_SAMPLES + 1, clock)
    assert len(rig.loop.soon) == 1


def test_a_ring_that_cannot_be_declared_leaves_the_callback_and_the_next_flood_tries_again(rig: Rig, clock: SimpleNamespace) -> None:
    rig.session.refuse_rings = True
    rig.put(FLOOD_SAMPLES + 1, clock)
    with pytest.raises(zenoh.ZError):
        rig.run_soon()
    assert not rig.guarded.flooded and rig.session.declared() == ["callback"] and rig.reports == []
    rig.put(1, clock)
    assert len(rig.loop.soon) == 1, "the next sample over the limit asks again"
    rig.session.refuse_rings = False
    rig.run_soon()
    assert rig.guarded.flooded


def test_a_flood_while_the_loop_is_closing_still_hands_every_sample_over(rig: Rig, clock: SimpleNamespace) -> None:
    rig.loop.closed = True
    rig.put(FLOOD_SAMPLES + 5, clock)
    assert len(rig.received) == FLOOD_SAMPLES + 5 and not rig.guarded.flooded


def test_a_change_asked_for_before_close_declares_nothing_after_it(rig: Rig, clock: SimpleNamespace) -> None:
    rig.put(FLOOD_SAMPLES + 1, clock)
    rig.guarded.close()
    rig.run_soon()
    assert rig.session.declared() == [] and not rig.guarded.flooded and rig.reports == []


def test_close_while_flooded_undeclares_the_ring_and_ends_the_pump(rig: Rig, clock: SimpleNamespace) -> None:
    rig.put(FLOOD_SAMPLES + 1, clock)
    rig.run_soon()
    rig.guarded.close()
    assert rig.session.declared() == [] and not rig.guarded.flooded
    assert not [t for t in threading.enumerate() if t.name == f"pump {KEY}"]


def test_a_key_with_a_wildcard_hands_over_the_last_chunk_of_each_samples_key(clock: SimpleNamespace) -> None:
    """A guarded ``cmd_vel/*`` tells its channel which source sent each sample."""
    received: list[tuple[str, bytes]] = []
    session = SimpleNamespace(declare_subscriber=lambda key, handler: Subscriber(handler))
    guarded = GuardedInput(session, "robot/cmd_vel/*", received.append, SimpleNamespace(loop=Loop()))  # type: ignore[arg-type]
    guarded.start()
    guarded._on_sample(SimpleNamespace(key_expr="robot/cmd_vel/dock", payload=SimpleNamespace(to_bytes=lambda: b"{}")))
    assert received == [("dock", b"{}")]
