"""The gateway service against the simulated robot, once over an in-memory link and once over TCP.

The same suite runs on both transports (the contract): the gateway cannot
tell them apart, and neither can these tests. No Zenoh here; inputs are the
bytes a Zenoh client would send, outputs are recorded.
"""

from __future__ import annotations

import asyncio
import functools
import itertools
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

import pytest
from helpers import MemoryLatchStore, RecordingOutput, free_port

from blackmetal.gateway.estop import read_estop
from blackmetal.gateway.host import GatewayHost
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.schemas import ErrorReport, GatewayHealth, RobotStatus, SimFaults, WheelImpulses
from blackmetal.sim.memory import MemoryConnector
from blackmetal.sim.physics import RobotParams, SimRobot
from blackmetal.sim.server import SimServer
from blackmetal.transport import TcpConnector

TIMEOUT = 20.0


@dataclass
class Rig:
    robot: SimRobot
    server: SimServer
    service: GatewayHost
    output: RecordingOutput
    stop: asyncio.Event
    task: asyncio.Task[None]

    def cmd_vel(self, payload: bytes) -> None:
        """A command from the source ``default``, as the loop takes it."""
        self.service.driver.take(self.service.core.on_cmd_vel, "default", payload)

    def estop(self, payload: bytes, release_key: bool = False) -> None:
        """A payload on ``estop`` (``release_key``: on ``estop/release``), as the loop takes it."""
        self.service.driver.take(self.service.core.on_estop, read_estop(payload, release_key=release_key))

    async def __aenter__(self) -> Rig:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def close(self) -> None:
        self.stop.set()
        await asyncio.wait_for(self.task, 5.0)
        await self.server.close()


async def until(condition: Callable[[], Any], what: str, timeout: float = TIMEOUT) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        await asyncio.sleep(0.01)


async def start_rig(transport: str, params: RobotParams | None = None, seed: int = 1, **settings: Any) -> Rig:
    robot = SimRobot(params, now=time.monotonic(), seed=seed)
    server = SimServer(robot, "127.0.0.1", 0, 0, log_interval=0.2)
    if transport == "tcp":
        await server.start()
        connector: Any = TcpConnector("127.0.0.1", server.control_port, server.log_port)
    else:
        connector = MemoryConnector(server)
    gw_settings = GatewaySettings(**settings)
    gw_settings.check()
    output = RecordingOutput()
    service = GatewayHost(gw_settings, connector, output, MemoryLatchStore())
    stop = asyncio.Event()
    task = asyncio.create_task(service.run(stop))
    rig = Rig(robot, server, service, output, stop, task)
    await until(lambda: service.control.connected and robot.counters["prepare"] >= 1, "the gateway to connect")
    return rig


def contract(test: Callable[..., Awaitable[None]]) -> Callable[..., None]:
    """Run an async test body on a fresh loop, for each transport."""

    @pytest.mark.parametrize("transport", ["memory", "tcp"])
    @functools.wraps(test)
    def wrapper(transport: str) -> None:
        asyncio.run(asyncio.wait_for(test(transport), 120))

    return wrapper


@contract
async def test_cmd_vel_moves_the_robot_and_a_left_turn_is_a_left_turn(transport: str) -> None:
    async with await start_rig(transport, cmd_timeout=0.0) as rig:
        # with and without trailing newline: what command-line clients send
        rig.cmd_vel(b'{"linear":{"x":0.2},"angular":{"z":0.4}}\n')
        await until(lambda: rig.robot.target_right > 0, "the command to reach the robot")
        assert rig.robot.target_right == pytest.approx(0.3) and rig.robot.target_left == pytest.approx(0.1)
        await asyncio.sleep(0.5)
        rig.robot.advance(time.monotonic())
        assert rig.robot.yaw > 0.1 and rig.robot.y > 0  # REP-103: +z turns left
        rig.cmd_vel(b'{"linear":{"x":0.1}}')
        await until(lambda: rig.robot.target_left == pytest.approx(0.1) and rig.robot.target_right == pytest.approx(0.1), "straight")
        # unchanged commands are not re-sent
        sent = rig.robot.counters["velocity_commands"]
        for _ in range(20):
            rig.cmd_vel(b'{"linear":{"x":0.1}}')
        await asyncio.sleep(0.2)
        assert rig.robot.counters["velocity_commands"] == sent
    # shutdown leaves the robot standing: zero velocity and NORMAL_STOP
    assert rig.robot.target_left == rig.robot.target_right == 0.0
    assert rig.robot.counters["normal_stops"] == 1


@contract
async def test_impulses_are_published_raw_with_sequence_and_stamps(transport: str) -> None:
    async with await start_rig(transport, poll_hz=100.0, cmd_timeout=0.0) as rig:
        rig.cmd_vel(b'{"linear":{"x":0.2}}')
        await until(lambda: len(rig.output.of(WheelImpulses)) > 150, "150 impulse samples")
        start = len(rig.output.of(WheelImpulses))
        t0 = time.monotonic()
        await asyncio.sleep(2.0)
        rate = (len(rig.output.of(WheelImpulses)) - start) / (time.monotonic() - t0)
        assert rate >= 95.0, f"{rate:.1f} Hz at --poll-hz 100"
        log = rig.output.of(WheelImpulses)
        assert [m.seq for m in log] == list(range(len(log)))
        assert all(b.stamp >= a.stamp for a, b in itertools.pairwise(log))
        moving = [m for m in log[-50:]]
        assert all(m.left in (202, 203) and m.right in (-211, -210) for m in moving)  # raw, right mirrored
        assert abs(log[-1].stamp - time.time()) < 5.0


@contract
async def test_command_timeout_brakes_within_timeout_plus_a_poll(transport: str) -> None:
    async with await start_rig(transport, cmd_timeout=0.3, poll_hz=50.0) as rig:
        started = time.monotonic()
        rig.cmd_vel(b'{"linear":{"x":0.2}}')
        await until(lambda: rig.robot.target_left > 0, "motion")
        await until(lambda: rig.robot.target_left == 0.0, "the command-timeout brake")
        assert time.monotonic() - started >= 0.29  # never before the timeout
        assert rig.service.health().cmd_timeout_active


@contract
async def test_keepalive_keeps_a_long_run_going_past_the_robot_watchdog(transport: str) -> None:
    # the robot's watchdog shortened to 1 s and the keep-alive to 0.4 s keep this quick
    async with await start_rig(transport, RobotParams(watchdog=1.0), cmd_timeout=0.0, keepalive=0.4) as rig:
        rig.cmd_vel(b'{"linear":{"x":0.1}}')
        await until(lambda: rig.robot.target_left > 0, "motion")
        await asyncio.sleep(3.0)
        rig.robot.advance(time.monotonic())
        assert rig.robot.moving and rig.robot.counters["watchdog_stops"] == 0
        assert rig.service.counters.keepalives >= 5


@contract
async def test_estop_latches_and_releases(transport: str) -> None:
    async with await start_rig(transport, cmd_timeout=0.0) as rig:
        rig.cmd_vel(b'{"linear":{"x":0.2}}')
        await until(lambda: rig.robot.target_left > 0, "motion")
        rig.estop(b'{"engaged": true}')
        await until(lambda: rig.robot.counters["emergency_stops"] == 1, "EMG_STOP at the robot")
        assert not rig.robot.moving and rig.service.health().estop
        rig.cmd_vel(b'{"linear":{"x":0.2}}')
        await asyncio.sleep(0.2)
        assert not rig.robot.moving
        assert any("emergency stop" in e.reason for e in rig.output.of(ErrorReport))
        rig.estop(b'{"engaged": false}\n', release_key=True)
        assert not rig.service.health().estop
        rig.cmd_vel(b'{"linear":{"x":0.15}}')
        await until(lambda: rig.robot.target_left == pytest.approx(0.15), "motion after release")


@contract
async def test_full_buffer_is_recovered(transport: str) -> None:
    async with await start_rig(transport, cmd_timeout=0.0, seed=5) as rig:
        rig.robot.faults = SimFaults(full_buffer=0.5)
        for speed in (0.1, 0.2, 0.3, 0.25, 0.15):
            rig.cmd_vel(b'{"linear":{"x":%.2f}}' % speed)
            await until(lambda s=speed: rig.robot.target_left == pytest.approx(s), f"{speed} m/s despite FULL_BUFFER")
        assert rig.robot.counters["full_buffer"] > 0
        assert rig.service.counters.full_buffer > 0 and rig.service.counters.full_buffer_retries > 0


@contract
async def test_garbled_link_keeps_impulses_flowing(transport: str) -> None:
    async with await start_rig(transport, cmd_timeout=0.0, poll_hz=100.0) as rig:
        rig.cmd_vel(b'{"linear":{"x":0.2}}')
        await until(lambda: rig.robot.target_left > 0, "motion")
        rig.robot.faults = SimFaults(garbage=0.3, split=0.3, glue=0.3)
        start = len(rig.output.of(WheelImpulses))
        await until(lambda: len(rig.output.of(WheelImpulses)) > start + 100, "impulses through garbage")
        assert rig.service.counters.malformed_replies > 0
        health = rig.service.health()
        assert health.garbage_bytes > 0 and health.control.state == "connected"
        recent = rig.output.of(WheelImpulses)[-30:]
        assert all(m.left in (202, 203) for m in recent)


@contract
async def test_reconnects_after_a_drop_and_never_resumes_old_motion(transport: str) -> None:
    async with await start_rig(transport, cmd_timeout=0.0) as rig:
        rig.cmd_vel(b'{"linear":{"x":0.2}}')
        await until(lambda: rig.robot.target_left > 0, "motion")
        dropped_at = time.monotonic()
        rig.server.drop_clients()
        await until(lambda: rig.robot.counters["prepare"] >= 2, "PREPARE after the reconnect")
        assert time.monotonic() - dropped_at < 3.0
        await until(lambda: rig.robot.target_left == 0.0, "zero velocity after the reconnect")
        count = len(rig.output.of(WheelImpulses))
        await until(lambda: len(rig.output.of(WheelImpulses)) > count + 10, "impulses to resume")
        await asyncio.sleep(0.3)
        assert rig.robot.target_left == 0.0  # the old 0.2 m/s was not replayed
        assert rig.service.health().control.reconnects >= 1


@contract
async def test_a_silent_robot_is_detected_and_reconnected(transport: str) -> None:
    async with await start_rig(transport, silence_timeout=0.5) as rig:
        rig.robot.faults = SimFaults(silent=True)
        await until(lambda: rig.service.control.reconnects >= 1, "a reconnect after silence")
        assert not rig.service.control.connected or rig.service.control.reconnects >= 1
        rig.robot.faults = SimFaults()
        start = len(rig.output.of(WheelImpulses))
        await until(lambda: len(rig.output.of(WheelImpulses)) > start + 10, "impulses after the robot speaks again")
        assert any("silent" in e.reason for e in rig.output.of(ErrorReport))


HOSTILE = [
    b"",
    b"\x00\xff\xfe garbage",
    b"not json",
    b'{"linear":{"x":NaN}}',
    b'{"linear":{"x":Infinity}}',
    b'{"linear":{"x":-Infinity},"angular":{"z":1}}',
    b'{"linear":{"x":1e308},"angular":{"z":1e308}}',
    b'{"linear":{"x":1e999}}',
    b'{"linear":{"x":"0.5"}}',
    b'{"linear":{"x":[0.5]}}',
    b'{"linear":{"x":true}}',
    b'{"linear":null}',
    b"[]",
    b"[0.5, 0.1]",
    b'"cmd"',
    b'{"angular":{"z":99999999999999999999999}}',
    b'{"linear":{"x":0.1}, "evil":"' + b"A" * 100 + b'"}',
    b'{"linear":' * 5000,
    b"{" + b" " * (1024 * 1024) + b"}",
]


@contract
async def test_hostile_payloads_are_reported_and_never_reach_the_robot(transport: str) -> None:
    rig = await start_rig(transport, cmd_timeout=0.0)
    seen: list[tuple[float, float]] = []
    original = rig.robot.handle

    def spy(request, now):  # type: ignore[no-untyped-def]
        if request.right is not None:
            seen.append((request.right, request.left))
        return original(request, now)

    rig.robot.handle = spy  # type: ignore[method-assign]
    try:
        rig.cmd_vel(b'{"linear":{"x":0.1}}')
        await until(lambda: rig.robot.target_left == pytest.approx(0.1), "a valid command")
        for _ in range(5):
            for payload in HOSTILE:
                rig.cmd_vel(payload)
        await asyncio.sleep(0.3)
        assert rig.robot.target_left == pytest.approx(0.1)  # the robot's command stayed as it was
        for _ in range(5):
            for payload in HOSTILE:
                rig.estop(payload)  # fails safe: engages the stop, and is reported
        await until(lambda: rig.robot.counters["emergency_stops"] >= 1, "EMG_STOP")
        assert rig.service.health().estop and not rig.robot.moving
        assert rig.service.counters.rejected_inputs == 2 * 5 * len(HOSTILE)
        assert rig.output.of(ErrorReport) and all(e.reason for e in rig.output.of(ErrorReport))
        assert len(rig.output.of(ErrorReport)) <= 40  # rate-limited
        assert all(abs(r) <= 0.8 and abs(left) <= 0.8 for r, left in seen)
        assert rig.server.malformed_requests == 0
        # and the gateway still serves once the stop is released
        rig.estop(b'{"engaged": false}', release_key=True)
        rig.cmd_vel(b'{"linear":{"x":0.05}}')
        await until(lambda: rig.robot.target_left == pytest.approx(0.05), "service after the burst")
    finally:
        await rig.close()


@contract
async def test_commands_while_the_link_is_down_are_refused_not_queued(transport: str) -> None:
    async with await start_rig(transport, cmd_timeout=0.0) as rig:
        await rig.server.close()  # the robot goes away entirely
        rig.server.drop_clients()
        await until(lambda: not rig.service.control.connected, "the link to go down")
        rig.cmd_vel(b'{"linear":{"x":0.3}}')
        assert any("link is down" in e.reason for e in rig.output.of(ErrorReport))
        assert rig.service.health().control.state in ("down", "connecting")


@contract
async def test_status_from_the_log_port(transport: str) -> None:
    async with await start_rig(transport) as rig:
        await until(lambda: len(rig.output.of(RobotStatus)) >= 1, "a status report")
        status = rig.output.of(RobotStatus)[0]
        assert (status.state_name, status.direction_name) == ("READY", "NORTH")
        rig.server.state = 3
        await until(lambda: rig.output.of(RobotStatus)[-1].state_name == "RUN", "a state change")
        await until(lambda: len(rig.output.of(GatewayHealth)) >= 2, "periodic health")


def test_an_unreachable_robot_is_reported_with_its_reason(caplog: pytest.LogCaptureFixture) -> None:
    """Nothing listens on the robot's port: the warning names the address and why, never an empty reason."""
    from blackmetal.gateway.host import _reason

    port = free_port()

    async def body() -> None:
        settings = GatewaySettings(control_port=port, log_port=port)
        host = GatewayHost(settings, TcpConnector("127.0.0.1", port, port, timeout=0.5), RecordingOutput(), MemoryLatchStore())
        stop = asyncio.Event()
        task = asyncio.create_task(host.run(stop))
        await until(lambda: caplog.text.count("cannot connect") >= 2, "both links to report")
        stop.set()
        await asyncio.wait_for(task, 5.0)

    with caplog.at_level("WARNING", logger="blackmetal.gateway"):
        asyncio.run(body())
    assert f"cannot connect to 127.0.0.1:{port}: connection refused (nothing listens on port {port}); retrying" in caplog.text
    assert _reason(TimeoutError()) == "TimeoutError" and _reason(OSError(113, "No route to host")) == "No route to host"


@pytest.mark.parametrize("where", ["timer", "handler"])
def test_a_bug_in_handling_fails_the_host_visibly_and_leaves_the_robot_standing(where: str) -> None:
    """A core that raises (a bug) ends run() with the exception, for a supervisor, after stopping the robot."""

    async def body() -> None:
        rig = await start_rig("memory", cmd_timeout=0.0)
        rig.cmd_vel(b'{"linear":{"x":0.2}}')
        await until(lambda: rig.robot.moving, "the robot to move")

        def broken(*_: object) -> None:
            raise RuntimeError("a bug")

        if where == "timer":
            rig.service.core.tick = broken  # type: ignore[method-assign]
        else:
            rig.service.core.on_cmd_vel = broken  # type: ignore[method-assign]
            handover_fail = rig.service.driver.fail
            try:
                rig.cmd_vel(b'{"linear":{"x":0.3}}')
            except RuntimeError as exc:
                handover_fail(exc)  # what the Zenoh edge's Intake does with a handler's exception
        with pytest.raises(RuntimeError, match="a bug"):
            await asyncio.wait_for(rig.task, 5.0)
        rig.robot.advance(time.monotonic())
        assert rig.robot.counters["normal_stops"] >= 1 and not rig.robot.moving
        await rig.server.close()

    asyncio.run(body())


@contract
async def test_inputs_taken_directly_on_another_thread_reach_the_robot_in_order(transport: str) -> None:
    """The direct path (a Zenoh thread holding the core lock) over either stream: sent at once where the stream can, else by the loop."""
    async with await start_rig(transport, cmd_timeout=0.0) as rig:
        service = rig.service

        def on_zenohs_thread(take: Callable[[Any], bool], item: Any) -> bool:
            with service.lock:  # as the intake takes it: under the core's lock, off the loop
                return take(item)

        loop = asyncio.get_running_loop()
        assert await loop.run_in_executor(
            None, on_zenohs_thread, service.direct(service.core.on_cmd_vel), ("default", b'{"linear":{"x":0.2}}')
        )
        await until(lambda: rig.robot.target_left > 0.19, "the directly taken command at the robot")
        estop = service.direct(service.core.on_estop, unpack=False)
        assert await loop.run_in_executor(None, on_zenohs_thread, estop, read_estop(b'{"engaged": true}'))
        await until(lambda: rig.robot.counters["emergency_stops"] == 1, "the directly taken e-stop at the robot")
        rig.cmd_vel(b'{"linear":{"x":0.2}}')  # refused on the loop: the stop taken on the other thread holds
        await until(lambda: any("emergency stop" in e.reason for e in rig.output.of(ErrorReport)), "the refused command's report")
        assert rig.robot.target_left == 0.0 and rig.server.malformed_requests == 0
