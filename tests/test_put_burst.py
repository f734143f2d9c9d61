"""A fleet's telemetry puts wait for the end of the loop's turn and then all go, in order (issue #29: Zenoh batches
puts made back to back). The real publishers, on an isolated session."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Coroutine
from typing import Any

import pytest
import zenoh

from blackmetal.runtime.burst import PutBurst

Run = Callable[[Coroutine[Any, Any, None]], None]


def collect(session: zenoh.Session, key: str) -> tuple[list[tuple[str, bytes]], threading.Condition, Any]:
    got: list[tuple[str, bytes]] = []
    arrived = threading.Condition()

    def on_sample(sample: zenoh.Sample) -> None:
        with arrived:
            got.append((str(sample.key_expr), sample.payload.to_bytes()))
            arrived.notify_all()

    return got, arrived, session.declare_subscriber(key, on_sample)


def test_puts_wait_for_the_end_of_the_turn_then_all_go_in_order(session: zenoh.Session, run_loop: Run) -> None:
    got, arrived, subscriber = collect(session, "burst/**")
    a, b = session.declare_publisher("burst/a"), session.declare_publisher("burst/b")
    burst = PutBurst()

    async def scenario() -> None:
        for i in range(3):
            burst.put(a, b"a%d" % i)
            burst.put(b, b"b%d" % i)
        assert len(burst) == 6
        with arrived:
            assert not arrived.wait_for(lambda: got, timeout=0.2)  # nothing put within the turn
        await asyncio.sleep(0)  # the turn ends
        assert len(burst) == 0
        burst.put(a, b"a3")  # a new burst, flushed at the end of the next turn
        await asyncio.sleep(0)

    try:
        run_loop(scenario())
        with arrived:
            assert arrived.wait_for(lambda: len(got) == 7, timeout=10), got
        assert [payload for key, payload in got if key == "burst/a"] == [b"a0", b"a1", b"a2", b"a3"]
        assert [payload for key, payload in got if key == "burst/b"] == [b"b0", b"b1", b"b2"]
    finally:
        subscriber.undeclare()


def test_a_put_refused_by_zenoh_is_dropped_and_the_rest_still_go(session: zenoh.Session, run_loop: Run) -> None:
    """A robot restarted after a bug closes its edge: its sample still held is dropped, the other robots' are not."""
    got, arrived, subscriber = collect(session, "burst/**")
    gone, kept = session.declare_publisher("burst/gone"), session.declare_publisher("burst/kept")
    burst = PutBurst()

    async def scenario() -> None:
        burst.put(gone, b"lost")
        burst.put(kept, b"one")
        gone.undeclare()
        burst.put(kept, b"two")
        await asyncio.sleep(0)

    try:
        run_loop(scenario())
        with arrived:
            assert arrived.wait_for(lambda: len(got) == 2, timeout=10), got
        assert got == [("burst/kept", b"one"), ("burst/kept", b"two")]
        assert burst.refused == 1
    finally:
        subscriber.undeclare()


def test_a_put_off_the_loop_is_refused_at_once() -> None:
    """Only the loop holds puts: a Zenoh thread or a test without a loop gets an error, not a put that never leaves."""
    with pytest.raises(RuntimeError, match="no running event loop"):
        PutBurst().put(None, b"x")  # type: ignore[arg-type]
