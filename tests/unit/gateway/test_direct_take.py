"""Commands and e-stops taken on the thread that delivers them, not after the gateway's loop wakes.

A Zenoh callback that finds the gateway's core free handles a command there
and sends it to the robot's socket at once (the hand-over's ``direct``
take). These tests stand in for Zenoh's thread with their own: the rules
that keep order and bound the work (unit, fake clock), a TCP stream's
immediate write, and the gateway whose loop is held busy while a command and
an e-stop still reach a robot on another thread.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from helpers import MemoryLatchStore, RecordingOutput, wait_for

from blackmetal.gateway.estop import read_estop
from blackmetal.gateway.host import GatewayHost
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.runtime.entry import loop_factory
from blackmetal.runtime.intake import DIRECT_BURST, DIRECT_WINDOW_S, Intake
from blackmetal.schemas import ErrorReport, GatewayHealth
from blackmetal.sim.physics import RobotParams, SimRobot
from blackmetal.sim.server import SimServer
from blackmetal.transport import TcpConnector, TcpStream


class LoopThread:
    """A running loop on its own thread, like a service's, that a test can hold busy."""

    def __init__(self, factory: Callable[[], asyncio.AbstractEventLoop] | None = None) -> None:
        self.loop = (factory or asyncio.new_event_loop)()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def run(self, coro: Any, timeout: float = 10.0) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def call(self, fn: Callable[[], Any], timeout: float = 10.0) -> Any:
        async def on_loop() -> Any:
            return fn()

        return self.run(on_loop(), timeout)

    def hold(self) -> threading.Event:
        """Keep the loop busy (in a callback, out of every core) until the returned event is set."""
        entered, release = threading.Event(), threading.Event()

        def busy() -> None:
            entered.set()
            release.wait(20)

        self.loop.call_soon_threadsafe(busy)
        assert entered.wait(10), "the loop never ran the holding callback"
        return release

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
        self.loop.close()


@pytest.fixture
def loop_thread() -> Iterator[LoopThread]:
    running = LoopThread()
    yield running
    running.close()


# --------------------------------------------------------------------------- the hand-over's rules


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class Rig:
    """A hand-over with an e-stop channel (priority 2) and a command channel (priority 1), both direct."""

    def __init__(self, loop_thread: LoopThread) -> None:
        self.loop_thread = loop_thread
        self.lock = threading.RLock()
        self.clock = FakeClock()
        self.errors: list[BaseException] = []
        self.intake = Intake(loop_thread.loop, on_error=self.errors.append, lock=self.lock, clock=self.clock)
        self.order: list[tuple[str, str]] = []  # (how, item) in the order they were handled
        self.fail_direct = False
        self.estop = self.intake.channel("estop", self._handled, priority=2, direct=self._direct)
        self.command = self.intake.channel("cmd", self._handled, priority=1, direct=self._direct)

    def _handled(self, item: str) -> None:
        self.order.append(("loop", item))

    def _direct(self, item: str) -> bool:
        if self.fail_direct:
            raise RuntimeError(f"bug handling {item}")
        self.order.append(("direct", item))
        return True

    def settled(self) -> None:
        """Wait until the loop has drained what was handed over."""
        self.loop_thread.call(lambda: None)
        self.loop_thread.call(lambda: None)


def test_an_input_is_taken_in_the_putting_thread_when_the_core_is_free(loop_thread: LoopThread) -> None:
    rig = Rig(loop_thread)
    release = loop_thread.hold()  # the loop is busy: only a direct take can handle the input now
    try:
        rig.command("a")
        rig.estop("stop")
        assert rig.order == [("direct", "a"), ("direct", "stop")]
    finally:
        release.set()
    rig.settled()
    assert rig.order == [("direct", "a"), ("direct", "stop")]  # nothing handled twice
    assert rig.intake.stats() == {"estop": (1, 0), "cmd": (1, 0)}


def test_while_the_core_is_held_inputs_wait_for_the_loop_and_keep_their_order(loop_thread: LoopThread) -> None:
    rig = Rig(loop_thread)
    release = loop_thread.hold()
    try:
        with rig.lock:  # another thread is in the core (the loop polling, say)
            done = threading.Event()
            threading.Thread(target=lambda: (rig.command("a"), rig.command("b"), done.set())).start()
            assert done.wait(10)
        # the core is free again, but "a" and "b" wait: a newer command must not overtake them
        rig.command("c")
        assert rig.order == []
    finally:
        release.set()
    rig.settled()
    assert rig.order == [("loop", "a"), ("loop", "b"), ("loop", "c")]
    rig.command("d")  # nothing waits any more: direct again
    assert rig.order[-1] == ("direct", "d")


def test_an_estop_is_taken_at_once_even_while_commands_wait(loop_thread: LoopThread) -> None:
    rig = Rig(loop_thread)
    release = loop_thread.hold()
    try:
        with rig.lock:
            waiting = threading.Thread(target=lambda: rig.command("a"))
            waiting.start()
            waiting.join(10)
        rig.estop("stop")  # the highest priority: the waiting command is no reason to wait
        rig.command("b")  # but a command still waits behind "a"
        assert rig.order == [("direct", "stop")]
    finally:
        release.set()
    rig.settled()
    assert rig.order == [("direct", "stop"), ("loop", "a"), ("loop", "b")]


def test_a_burst_beyond_the_direct_budget_waits_for_the_loop(loop_thread: LoopThread) -> None:
    rig = Rig(loop_thread)
    release = loop_thread.hold()
    try:
        for i in range(DIRECT_BURST + 5):
            rig.command(str(i))
        assert [item for how, item in rig.order if how == "direct"] == [str(i) for i in range(DIRECT_BURST)]
        rig.clock.now += DIRECT_WINDOW_S * 1.01  # a new window; but older items wait, so still none direct
        rig.command("late")
        assert len(rig.order) == DIRECT_BURST
    finally:
        release.set()
    rig.settled()
    assert [item for _, item in rig.order] == [str(i) for i in range(DIRECT_BURST + 5)] + ["late"]
    rig.command("next")
    assert rig.order[-1] == ("direct", "next")


def test_a_direct_take_that_fails_is_reported_on_the_loop(loop_thread: LoopThread) -> None:
    rig = Rig(loop_thread)
    rig.fail_direct = True
    rig.command("a")
    rig.settled()
    assert [str(e) for e in rig.errors] == ["bug handling a"]
    assert rig.order == []  # taken (and failed): not handled a second time


def test_a_direct_channel_needs_the_lock(loop_thread: LoopThread) -> None:
    with pytest.raises(ValueError, match="lock"):
        Intake(loop_thread.loop).channel("cmd", print, direct=lambda item: True)


# --------------------------------------------------------------------------- a TCP stream's immediate write


def test_a_tcp_stream_writes_now_from_another_thread_and_its_close_ends_the_link(loop_thread: LoopThread) -> None:
    with socket.create_server(("127.0.0.1", 0)) as server:
        port = server.getsockname()[1]

        async def connect() -> TcpStream:
            return await TcpStream.connect("127.0.0.1", port, write_now=True)

        stream = loop_thread.run(connect())
        peer, _ = server.accept()
        with peer:
            peer.settimeout(10)
            assert stream.write_now(b"hello") == 5  # this test's thread, not the loop's
            assert peer.recv(16) == b"hello"
            loop_thread.call(stream.close)
            # our own duplicate of the socket went with it: the robot sees the link end
            assert peer.recv(16) == b""


def test_a_tcp_stream_sends_nothing_now_while_the_loop_has_bytes_queued(loop_thread: LoopThread) -> None:
    with socket.create_server(("127.0.0.1", 0)) as server:
        port = server.getsockname()[1]

        async def connect_and_fill() -> TcpStream:
            stream = await TcpStream.connect("127.0.0.1", port, write_now=True)
            stream.write(b"x" * 20_000_000)  # far more than the socket buffers: the rest waits in the loop's queue
            return stream

        stream = loop_thread.run(connect_and_fill())
        peer, _ = server.accept()
        with peer:
            assert stream.write_now(b"late") == 0  # it would overtake the queued bytes
            loop_thread.call(stream.close)


# --------------------------------------------------------------------------- the gateway, its loop held busy


class HalfNowStream:
    """A TCP stream that sends only half of what it is asked to send now: the rest is the loop's to send, first."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner

    def write_now(self, data: bytes) -> int:
        return int(self.inner.write_now(data[: max(1, len(data) // 2)]))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


class HalfNowConnector(TcpConnector):
    async def open(self, port: str) -> Any:
        return HalfNowStream(await super().open(port))


class GatewayRig:
    """The simulated robot on one loop thread, the gateway on another, inputs put from the test's thread as Zenoh's would be."""

    def __init__(self, connector_type: type[TcpConnector] = TcpConnector, output: RecordingOutput | None = None) -> None:
        self.robot_thread = LoopThread()
        self.gateway_thread = LoopThread(loop_factory())  # the services' own loop: uvloop where it is installed
        self.robot = SimRobot(RobotParams(), now=time.monotonic(), seed=1)
        self.server = SimServer(self.robot, "127.0.0.1", 0, 0, log_interval=0.2)
        self.robot_thread.run(self.server.start())
        settings = GatewaySettings(cmd_timeout=0.0)
        settings.check()
        self.output = output or RecordingOutput()
        host = self.host = GatewayHost(
            settings, connector_type("127.0.0.1", self.server.control_port, self.server.log_port), self.output, MemoryLatchStore()
        )
        self.stop = self.gateway_thread.call(asyncio.Event)
        self.task = asyncio.run_coroutine_threadsafe(host.run(self.stop), self.gateway_thread.loop)
        # wired as GatewayZenoh.attach wires a single robot's gateway
        driver, core = host.driver, host.core
        intake = Intake(self.gateway_thread.loop, on_error=driver.fail, lock=host.lock, after_drain=driver.publish)
        on_estop = driver.handler(core.on_estop, unpack=False)
        estop = intake.channel("estop", on_estop, latest=True, priority=2, direct=host.direct(core.on_estop, unpack=False))
        self.estop = lambda payload: estop(read_estop(payload))
        self.command = intake.channel(
            "cmd_vel", driver.handler(core.on_cmd_vel), capacity=64, priority=1, direct=host.direct(core.on_cmd_vel)
        )
        self.intake = intake
        wait_for(lambda: host.control.connected and self.robot.counters["prepare"] >= 1, what="the gateway to connect")

    def direct_taken(self) -> dict[str, int]:
        return {channel.name: channel.direct_taken for channel in self.intake._channels}

    def close(self) -> None:
        self.gateway_thread.loop.call_soon_threadsafe(self.stop.set)
        with contextlib.suppress(Exception):  # a test that failed the host on purpose has seen its failure
            self.task.result(10)
        self.robot_thread.run(self.server.close())
        self.gateway_thread.close()
        self.robot_thread.close()


@pytest.fixture
def gateway_rig() -> Iterator[GatewayRig]:
    rig = GatewayRig()
    yield rig
    rig.close()


def test_a_command_and_an_estop_reach_the_robot_while_the_gateways_loop_is_busy(gateway_rig: GatewayRig) -> None:
    rig = gateway_rig
    release = rig.gateway_thread.hold()
    try:
        rig.command(("default", b'{"linear":{"x":0.2}}'))
        wait_for(lambda: rig.robot.target_left > 0, timeout=10, what="the command at the robot, the gateway's loop busy")
        rig.estop(b'{"engaged": true}')
        wait_for(lambda: rig.robot.counters["emergency_stops"] == 1, timeout=10, what="EMG_STOP at the robot, the loop busy")
        assert not any(h.estop for h in rig.output.of(GatewayHealth))  # reports wait for the loop; only the robot could not
    finally:
        release.set()
    wait_for(lambda: any(h.estop for h in rig.output.of(GatewayHealth)), what="the e-stop's health report, from the loop")
    assert rig.intake.stats() == {"estop": (1, 0), "cmd_vel": (1, 0)}
    assert rig.direct_taken() == {"estop": 1, "cmd_vel": 1}
    # and the e-stop latched in the one core, whichever thread took it
    rig.command(("default", b'{"linear":{"x":0.2}}'))
    wait_for(lambda: any("emergency stop" in e.reason for e in rig.output.of(ErrorReport)), what="the refused command's report")
    assert rig.server.malformed_requests == 0


def test_what_a_direct_take_could_not_send_goes_before_anything_newer() -> None:
    rig = GatewayRig(HalfNowConnector)
    try:
        for speed in (0.1, 0.2, 0.15):  # half now, the rest from the loop's flush
            rig.command(("default", b'{"linear":{"x":%.2f}}' % speed))
            wait_for(lambda s=speed: rig.robot.target_left == pytest.approx(s), timeout=10, what=f"{speed} m/s at the robot")
        release = rig.gateway_thread.hold()
        try:  # two direct takes before the loop can send anything: the e-stop's bytes follow the command's rest
            rig.command(("default", b'{"linear":{"x":0.25}}'))
            rig.estop(b'{"engaged": true}')
        finally:
            release.set()
        wait_for(lambda: rig.robot.counters["emergency_stops"] == 1, timeout=10, what="EMG_STOP at the robot")
        assert rig.server.malformed_requests == 0  # every request whole, and in order, however it was split
        assert rig.direct_taken() == {"estop": 1, "cmd_vel": 4}
    finally:
        rig.close()


class BrokenOutput(RecordingOutput):
    """An output whose next health report fails once it is told to (a bug, or a broken session), once."""

    broken = False

    def __call__(self, message: Any) -> None:
        if self.broken and isinstance(message, GatewayHealth):
            self.broken = False
            raise RuntimeError("output broke")
        super().__call__(message)


def test_a_failure_in_the_flush_after_a_direct_take_fails_the_host_and_stops_direct_takes() -> None:
    output = BrokenOutput()
    rig = GatewayRig(output=output)
    try:
        output.broken = True
        rig.estop(b'{"engaged": true}')  # taken directly; its health report, published by the loop's flush, fails
        with pytest.raises(RuntimeError, match="output broke"):
            rig.task.result(10)  # run() ends with the failure, for a supervisor to restart
        assert rig.robot.counters["emergency_stops"] == 1
        rig.command(("default", b'{"linear":{"x":0.2}}'))
        assert rig.direct_taken()["cmd_vel"] == 0  # the failed host's core is driven by nobody any more
        assert rig.robot.target_left == 0.0
    finally:
        rig.close()
