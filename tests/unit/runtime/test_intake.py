"""The intake's fairness rules: one bounded slot per input, an e-stop ON that no storm can hide, no publishing under the core lock.

The hand-over is driven from the test's thread as Zenoh's threads would;
the gateway rig (tests/unit/gateway/test_direct_take.py) runs a real gateway host on
its own loop against the simulated robot over TCP.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import Any

import pytest
from helpers import RecordingOutput, wait_for

from blackmetal.gateway.estop import read_estop
from blackmetal.gateway.zenoh_edge import _engages
from blackmetal.runtime.driver import CoreLock
from blackmetal.runtime.intake import Intake
from blackmetal.schemas import DriverChange, ErrorReport, GatewayHealth, WheelImpulses
from unit.gateway.test_direct_take import GatewayRig, LoopThread

ON, OFF = b'{"engaged": true}', b'{"engaged": false}'


@pytest.fixture
def loop_thread() -> Iterator[LoopThread]:
    running = LoopThread()
    yield running
    running.close()


def settle(loop_thread: LoopThread) -> None:
    loop_thread.call(lambda: None)
    loop_thread.call(lambda: None)


class GatewayInputs:
    """The gateway's wiring of one e-stop slot and two command sources, with the loop held while the test puts."""

    def __init__(self, loop_thread: LoopThread) -> None:
        self.loop_thread = loop_thread
        self.handled: list[tuple[str, object]] = []
        self.superseded: dict[str, int] = {}
        intake = self.intake = Intake(loop_thread.loop, lock=CoreLock())
        self.estop = intake.channel("estop", lambda item: self.handled.append(("estop", item)), latest=True, latch=_engages, priority=2)
        self.sources = {
            name: intake.channel(
                f"cmd_vel/{name}",
                lambda item: self.handled.append(item),
                latest=True,
                priority=1,
                on_dropped=lambda count, name=name: self.superseded.__setitem__(name, self.superseded.get(name, 0) + count),
            )
            for name in ("teleop", "nav")
        }


def test_a_flood_of_one_source_neither_masks_nor_delays_another(loop_thread: LoopThread) -> None:
    intake = GatewayInputs(loop_thread)
    release = loop_thread.hold()
    try:
        for i in range(5000):
            intake.sources["nav"](("nav", b"nav %d" % i))
            if i == 2500:
                intake.sources["teleop"](("teleop", b"teleop"))
    finally:
        release.set()
    settle(loop_thread)
    assert ("teleop", b"teleop") in intake.handled  # a flood of nav never pushes teleop's command out
    assert intake.handled.count(("nav", b"nav 4999")) == 1 and len(intake.handled) == 2  # nav: only its newest
    assert intake.superseded == {"nav": 4999}  # counted against nav, and nav alone
    assert intake.intake.stats()["cmd_vel/nav"] == (5000, 4999)


@pytest.mark.parametrize(
    ("storm", "expected"),
    [
        ([ON, OFF], [ON, OFF]),  # an ON is acted on even when a release follows before the loop looks
        ([OFF, ON], [ON]),  # the newest state wins: the older release is dropped
        ([ON, OFF] * 500 + [ON], [ON, ON]),  # a storm that ends on ON ends engaged: two handlings, not a thousand
        ([ON, OFF] * 500, [ON, OFF]),
        ([b"garbage", OFF], [b"garbage", OFF]),  # anything but a release engages: latched like an ON
    ],
)
def test_an_estop_storm_is_two_handlings_at_most_and_the_newest_state_wins(
    loop_thread: LoopThread, storm: list[bytes], expected: list[bytes]
) -> None:
    intake = GatewayInputs(loop_thread)
    release = loop_thread.hold()
    try:
        for payload in storm:
            intake.estop(read_estop(payload))
            intake.sources["nav"](("nav", b"go"))
    finally:
        release.set()
    settle(loop_thread)
    assert [item for kind, item in intake.handled if kind == "estop"] == [read_estop(item) for item in expected]
    assert intake.handled[: len(expected)] == [("estop", read_estop(item)) for item in expected]  # ahead of every command


def test_no_command_is_taken_directly_while_an_estop_on_waits(loop_thread: LoopThread) -> None:
    lock = CoreLock()
    intake = Intake(loop_thread.loop, lock=lock)
    order: list[str] = []
    estop = intake.channel("estop", lambda item: order.append("estop"), latest=True, latch=_engages, priority=2)
    command = intake.channel(
        "cmd", lambda item: order.append("loop cmd"), latest=True, priority=1, direct=lambda item: order.append("direct cmd") is None
    )
    release = loop_thread.hold()
    try:
        with lock:  # the loop is in the core: the ON cannot be taken directly, it waits in its slot
            estop(read_estop(ON))
        command(("default", b"go"))  # the core is free now, but the ON waits: no command overtakes it
        assert order == []
    finally:
        release.set()
    settle(loop_thread)
    assert order == ["estop", "loop cmd"]


class BlockingOutput(RecordingOutput):
    """An output whose health put blocks until released, as a Zenoh put with BLOCK does on a dead link."""

    def __init__(self) -> None:
        super().__init__()
        self.armed = threading.Event()
        self.blocked = threading.Event()
        self.unblock = threading.Event()

    def __call__(self, message: Any) -> None:
        if isinstance(message, GatewayHealth) and self.armed.is_set() and not self.blocked.is_set():
            self.blocked.set()
            self.unblock.wait(20)
        super().__call__(message)


def test_a_publication_that_blocks_does_not_delay_an_estops_bytes_to_the_robot() -> None:
    output = BlockingOutput()
    rig = GatewayRig(output=output)
    try:
        output.armed.set()
        assert output.blocked.wait(10), "the gateway never published its health"
        # the loop is stuck in a put: an e-stop from Zenoh's thread still reaches the robot, directly
        rig.estop(ON)
        wait_for(lambda: rig.robot.counters["emergency_stops"] == 1, timeout=10, what="EMG_STOP while a put blocks the loop")
    finally:
        output.unblock.set()
        rig.close()


class LockCheckingOutput(RecordingOutput):
    """Notes every message handed over while the publishing thread holds the gateway's core lock."""

    def __init__(self) -> None:
        super().__init__()
        self.lock: CoreLock | None = None
        self.under_lock: list[str] = []

    def _check(self, kind: str) -> None:
        if self.lock is not None and self.lock.held():
            self.under_lock.append(kind)

    def __call__(self, message: Any) -> None:
        self._check(type(message).__name__)
        super().__call__(message)


def test_nothing_is_published_while_the_core_lock_is_held() -> None:
    output = LockCheckingOutput()
    rig = GatewayRig(output=output)
    output.lock = rig.host.lock
    try:
        rig.command(("default", b'{"linear":{"x":0.2}}'))  # taken directly
        held, release = threading.Event(), threading.Event()

        def hold_the_core() -> None:  # as the loop does while it is in the core
            with rig.host.lock:
                held.set()
                release.wait(10)

        holder = threading.Thread(target=hold_the_core)
        holder.start()
        assert held.wait(10)
        rig.command(("nosuchsource", b'{"linear":{"x":0.2}}'))  # a report, handled by a drain under the lock
        rig.estop(ON)  # and a health report
        release.set()
        holder.join(10)
        rig.estop(OFF)
        wait_for(
            lambda: len(output.of(WheelImpulses)) > 20 and output.of(ErrorReport) and output.of(DriverChange),
            what="impulses, errors and a driver",
        )
        count = len(output.of(GatewayHealth))
        wait_for(lambda: len(output.of(GatewayHealth)) > count, what="a health report after the e-stop")
    finally:
        rig.close()
    assert output.under_lock == []


def test_a_closed_intake_hands_nothing_over_and_a_drain_already_scheduled_does_nothing(loop_thread: LoopThread) -> None:
    """An edge closes its intake before it undeclares its publishers: a drain scheduled just before must not publish
    through them (the odometry printed 'Undeclared publisher' tracebacks at exit)."""
    handled: list[bytes] = []
    intake = Intake(loop_thread.loop)
    put = intake.channel("impulses", handled.append)
    release = loop_thread.hold()
    try:
        put(b"scheduled before the close")  # its drain waits for the held loop
        intake.close()
        put(b"after the close")
    finally:
        release.set()
    settle(loop_thread)
    assert handled == []
    assert intake.stats()["impulses"] == (1, 0)
