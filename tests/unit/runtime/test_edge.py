"""The Zenoh edge's own lifecycle: what it declares goes when it closes, a flooded input changes over and back, pumps end.

One in-process peer session, no endpoints: nothing leaves the process.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Iterator

import pytest
import zenoh
from helpers import wait_for

from blackmetal.runtime.edge import ZenohEdge
from blackmetal.runtime.flood import FLOOD_SAMPLES, PUMP_JOIN_S, GuardedInput
from blackmetal.runtime.intake import Intake


def _matching(publisher: zenoh.Publisher) -> bool:
    """Whether a subscriber matches (the stubs say bool; zenoh 1.x returns a MatchingStatus)."""
    status = publisher.matching_status
    return bool(getattr(status, "matching", status))


def _pumps() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("pump ")]


def _on_loop(loop: asyncio.AbstractEventLoop, call: Callable[[], None]) -> float:
    """Run ``call`` on the loop's thread, as a service closes its edge; how long the loop was held."""

    async def timed() -> float:
        start = time.monotonic()
        call()
        return time.monotonic() - start

    return asyncio.run_coroutine_threadsafe(timed(), loop).result(10)


@pytest.fixture
def loop() -> Iterator[asyncio.AbstractEventLoop]:
    """A running loop on its own thread, like a service's."""
    running = asyncio.new_event_loop()
    thread = threading.Thread(target=running.run_forever, daemon=True)
    thread.start()
    yield running
    running.call_soon_threadsafe(running.stop)
    thread.join(5)
    running.close()


def test_a_guarded_input_takes_samples_by_callback_and_keeps_no_thread(session: zenoh.Session, loop: asyncio.AbstractEventLoop) -> None:
    """At sane rates there is no pump thread: zenoh-python wakes a blocked recv() ten times a second, GIL and all."""
    intake = Intake(loop)
    received: list[tuple[str, bytes]] = []
    edge = ZenohEdge(session)
    guarded = edge.guarded("edge/test/cmd_vel/*", intake.channel("cmd_vel", received.append), intake)
    publisher = session.declare_publisher("edge/test/cmd_vel/nav")
    for i in range(20):
        publisher.put(f"{i}".encode())
    wait_for(lambda: len(received) == 20, what="20 samples")
    assert received[0] == ("nav", b"0") and not guarded.flooded and not _pumps()
    _on_loop(loop, edge.close)
    assert not _matching(publisher), "the guarded subscriber is still declared"


def test_a_flood_goes_through_the_ring_buffer_and_back_when_it_ends(session: zenoh.Session, loop: asyncio.AbstractEventLoop) -> None:
    """A flood changes the input over to Zenoh's ring buffer and one pump; quiet again, it changes back; nothing is lost at either change."""
    intake = Intake(loop)
    received: list[tuple[str, bytes]] = []
    reports: list[tuple[str, str]] = []
    guarded = GuardedInput(session, "edge/test/cmd_vel/*", intake.channel("cmd_vel", received.append), intake,
                           lambda key, reason: reports.append((key, reason)), quiet_s=0.3)  # fmt: skip
    guarded.start()
    publisher = session.declare_publisher("edge/test/cmd_vel/flood")
    try:
        for i in range(5 * FLOOD_SAMPLES):
            publisher.put(f"{i}".encode())
        wait_for(lambda: guarded.flooded and reports, what="the change to the ring buffer, reported")  # both on the loop
        assert [t.name for t in _pumps()] == ["pump edge/test/cmd_vel/*"]
        assert "floods" in reports[0][1] and reports[0][0] == "edge/test/cmd_vel/*", reports
        publisher.put(b"last of the flood")  # through the ring and the pump
        # the newest comes last: the pump waits for the old callback to hand over what it had queued
        wait_for(lambda: ("flood", b"last of the flood") in received, what="the pumped sample")
        time.sleep(0.2)
        assert received[-1] == ("flood", b"last of the flood"), received[-3:]

        wait_for(lambda: not guarded.flooded and len(reports) == 2, timeout=10, what="the change back to a callback, reported")
        assert "over" in reports[-1][1], reports
        wait_for(lambda: not _pumps(), what="the pump's end")
        publisher.put(b"after")
        wait_for(lambda: ("flood", b"after") in received, what="a sample by callback again")
        assert not _pumps()
    finally:
        _on_loop(loop, guarded.close)
    assert not _matching(publisher)


def test_closing_flooded_inputs_ends_their_pumps_at_once(session: zenoh.Session, loop: asyncio.AbstractEventLoop) -> None:
    """A pump blocked on its subscriber must wake and end when the edge closes, without holding the loop.

    It once waited on the subscriber itself, which kept the subscriber borrowed:
    ``undeclare()`` failed, the pump stayed inside Zenoh, and at exit CPython
    ended that thread mid-unwind, aborting the gateway ("FATAL: exception not rethrown").
    And closing once joined each pump while it waited up to 0.1 s for a drain that
    only the (now blocked) loop could do: 0.2-0.3 s for three flooded inputs, in a
    fleet a pause of every robot's e-stop.
    """
    intake = Intake(loop)
    edge = ZenohEdge(session)
    inputs = [edge.guarded(f"edge/test/{i}/cmd_vel/*", intake.channel(f"cmd_vel {i}", lambda item: None), intake) for i in range(3)]
    publishers = [session.declare_publisher(f"edge/test/{i}/cmd_vel/nav") for i in range(3)]
    for publisher in publishers:
        for i in range(5 * FLOOD_SAMPLES):
            publisher.put(f"{i}".encode())
    wait_for(lambda: all(guarded.flooded for guarded in inputs), what="the change to the ring buffers")
    for publisher in publishers:
        publisher.put(b"keep the pumps busy")
    assert len(_pumps()) == 3 and all(_matching(publisher) for publisher in publishers)

    held = _on_loop(loop, edge.close)
    assert not _pumps(), f"pump threads still running {PUMP_JOIN_S} s after close: {_pumps()}"
    assert not any(_matching(publisher) for publisher in publishers), "a pumped subscriber is still declared"
    assert held < 0.1, f"closing held the loop {held:.3f} s"


def test_telemetry_is_dropped_for_a_congested_link_and_commands_never_are(session: zenoh.Session) -> None:
    """Issue #29: a BLOCK publisher makes a router wait on a dead link, stalling every other host's traffic behind it.
    The key space says how each publication travels; the edge declares it so, whatever service publishes."""
    from blackmetal.schemas import KEY_SPECS, Delivery, Keys, delivery_of

    keys = Keys("fleet/r7")
    commands = {"cmd_vel", "cmd_vel_source", "lock", "estop", "estop_release", "sim_faults"}
    for spec in KEY_SPECS:
        assert (spec.delivery is None) == (spec.kind != "publication"), spec.name
        if spec.delivery is not None:
            assert (spec.delivery is Delivery.COMMAND) == (spec.name in commands), spec.name
    edge = ZenohEdge(session)
    try:
        for key in (keys.pose, keys.impulses, keys.health, keys.status, keys.errors, keys.driver, keys.params, keys.sim_truth):
            assert delivery_of(key, keys.prefix) is Delivery.TELEMETRY
            assert edge.publisher(keys, key).congestion_control == zenoh.CongestionControl.DROP, key
        for key in (keys.cmd_vel, keys.cmd_vel_of("nav"), keys.lock_of("dock"), keys.estop, keys.estop_release, keys.sim_faults):
            assert delivery_of(key, keys.prefix) is Delivery.COMMAND
            assert edge.publisher(keys, key).congestion_control == zenoh.CongestionControl.BLOCK, key
        with pytest.raises(ValueError, match="not a blackmetal publication key"):
            edge.publisher(keys, keys.params_set)  # a query key: nothing is published on it
    finally:
        edge.close()
