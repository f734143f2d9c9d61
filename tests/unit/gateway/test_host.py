"""The gateway host's send rules for a direct take: what goes to the robot now, what the loop sends after, what never goes.

The host runs on a real loop (``GatewayHost.run``) over fake robot streams;
a direct take is made as the intake makes it (holding the core lock) on
another thread, as Zenoh's would be. The take through a whole host over TCP
is in tests/unit/gateway/test_direct_take.py; the driver's rule of who may
take directly is in tests/unit/runtime/test_driver.py.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import Any

from helpers import MemoryLatchStore, RecordingOutput

from blackmetal import wire
from blackmetal.gateway.estop import read_estop
from blackmetal.gateway.host import GatewayHost
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.schemas import ErrorReport
from blackmetal.wire import CommandCode

EMG_STOP = wire.encode_request(wire.simple(CommandCode.EMG_STOP))


class Stream:
    """A robot stream that takes ``room`` bytes at once from another thread; records what went now and what the loop wrote."""

    def __init__(self, room: int = 1 << 20) -> None:
        self.room = room
        self.sent = b""  # by write_now, on the taking thread
        self.written = b""  # by write, on the loop
        self.calls = 0
        self.closing = False
        self.ended = asyncio.Event()

    async def pump(self, deliver: Callable[[bytes], None]) -> None:
        await self.ended.wait()

    def write(self, data: bytes) -> None:
        self.written += data

    def write_now(self, data: bytes) -> int:
        self.calls += 1
        taken = data[: self.room]
        self.room -= len(taken)
        self.sent += taken
        return len(taken)

    async def drain(self) -> None:
        pass

    def close(self) -> None:
        self.closing = True
        self.ended.set()

    def is_closing(self) -> bool:
        return self.closing


class Connector:
    """Opens a new :class:`Stream` for each connection; the log link's never ends either."""

    def __init__(self) -> None:
        self.opened: dict[str, list[Stream]] = {"control": [], "log": []}
        self.room = 1 << 20

    async def open(self, port: str) -> Stream:
        stream = Stream(self.room)
        self.opened[port].append(stream)
        return stream

    def describe(self, port: str) -> str:
        return f"fake:{port}"


def command(speed: float) -> tuple[str, bytes]:
    return "default", b'{"linear":{"x":%.3f}}' % speed


def velocity(speed: float) -> bytes:
    """The wire bytes' mark of a velocity command for ``speed`` (both wheels, no turn)."""
    return b'"LeftWheelSpeed":%.6f' % speed


async def until(condition: Callable[[], bool]) -> None:
    for _ in range(500):
        if condition():
            return
        await asyncio.sleep(0.01)
    raise AssertionError("condition never met")


def hosted(test: Callable[[GatewayHost, Connector, RecordingOutput], Awaitable[None]], room: int = 1 << 20) -> None:
    """Run ``test`` against a serving host whose control link is up (its first stream's opening bytes already written)."""

    async def main() -> None:
        settings = GatewaySettings(cmd_timeout=0.0, unsafe_start_released=True)
        settings.check()
        connector, output = Connector(), RecordingOutput()
        connector.room = room
        host = GatewayHost(settings, connector, output, MemoryLatchStore())
        stop = asyncio.Event()
        run = asyncio.create_task(host.run(stop))
        await until(lambda: host.control.connected)
        await asyncio.sleep(0.01)  # past the rate cap of the opening stop (max_command_hz); no reply is ever due in 0.5 s
        try:
            await test(host, connector, output)
        finally:
            stop.set()
            await run

    asyncio.run(main())


def take(host: GatewayHost, item: Any, method: Any = None) -> Awaitable[bool]:
    """A direct take on another thread, holding the core lock as the intake does."""
    direct = host.direct(method or host.core.on_cmd_vel)

    def on_zenoh_thread() -> bool:
        with host.lock:
            return direct(item)

    return asyncio.to_thread(on_zenoh_thread)


def count_flushes(host: GatewayHost) -> list[int]:
    flushes: list[int] = []
    flush = host._flush_after_direct

    def counted() -> None:
        flushes.append(1)
        flush()

    host._flush_after_direct = counted  # type: ignore[method-assign]
    return flushes


def test_bytes_go_to_the_robot_at_once_on_the_taking_thread() -> None:
    async def test(host: GatewayHost, connector: Connector, output: RecordingOutput) -> None:
        stream = connector.opened["control"][0]
        assert await take(host, command(0.1))
        assert velocity(0.1) in stream.sent, "sent on the taking thread, before the loop wakes"
        await asyncio.sleep(0.01)
        assert velocity(0.1) not in stream.written, "and not again by the loop"

    hosted(test)


def test_takes_before_the_loops_turn_share_one_flush() -> None:
    async def test(host: GatewayHost, connector: Connector, output: RecordingOutput) -> None:
        flushes = count_flushes(host)
        direct = host.direct(host.core.on_cmd_vel)

        def two_takes() -> list[bool]:
            with host.lock:
                return [direct(command(0.1)), direct(command(0.2))]

        assert await asyncio.to_thread(two_takes) == [True, True]  # the loop waits in to_thread: no turn between them
        await asyncio.sleep(0.01)
        assert flushes == [1], "one flush for the inputs taken before the loop's turn, not one each"
        assert await take(host, command(0.3))
        await asyncio.sleep(0.01)
        assert flushes == [1, 1], "a take after the flush schedules the next one"

    hosted(test)


def test_what_the_stream_could_not_take_now_goes_first_in_the_loops_next_write_and_only_once() -> None:
    async def test(host: GatewayHost, connector: Connector, output: RecordingOutput) -> None:
        stream = connector.opened["control"][0]
        stream.room, stream.sent, stream.written = 4, b"", b""
        assert await take(host, command(0.1))
        assert len(stream.sent) == 4
        await asyncio.sleep(0.01)  # the flush
        whole = stream.sent + stream.written
        assert velocity(0.1) in whole and stream.written.startswith(whole[4:]), "the rest, oldest first"
        assert whole.count(velocity(0.1)) == 1, "and only once"
        stream.room = 1 << 20
        assert await take(host, command(0.2))
        assert stream.sent.count(velocity(0.1)) + stream.written.count(velocity(0.1)) <= 1

    hosted(test)


def test_a_direct_take_after_a_rest_sends_the_rest_first() -> None:
    async def test(host: GatewayHost, connector: Connector, output: RecordingOutput) -> None:
        stream = connector.opened["control"][0]
        stream.room, stream.sent, stream.written = 4, b"", b""
        direct = host.direct(host.core.on_cmd_vel)

        stop = host.direct(host.core.on_estop, unpack=False)

        def rest_then_more() -> None:
            with host.lock:
                direct(command(0.1))
                stream.room = 1 << 20
                stop(read_estop(b'{"engaged": true}'))

        await asyncio.to_thread(rest_then_more)  # the loop does not turn between the two
        assert stream.written == b""
        assert stream.sent.index(velocity(0.1)) < stream.sent.index(EMG_STOP), "whole, and in order"

    hosted(test)


def test_nothing_is_written_to_a_closing_link() -> None:
    async def test(host: GatewayHost, connector: Connector, output: RecordingOutput) -> None:
        stream = connector.opened["control"][0]
        stream.closing, stream.calls = True, 0
        written = stream.written
        assert await take(host, command(0.1))
        await asyncio.sleep(0.01)
        assert stream.calls == 0 and velocity(0.1) not in stream.sent
        assert stream.written == written

    hosted(test)


def test_bytes_meant_for_a_link_that_went_never_reach_the_next_one() -> None:
    """A reconnect never resumes old motion: what a direct take could not send goes with its link."""

    async def test(host: GatewayHost, connector: Connector, output: RecordingOutput) -> None:
        old = connector.opened["control"][0]
        old.room = 0
        direct = host.direct(host.core.on_cmd_vel)

        def take_then_lose_the_link() -> None:
            with host.lock:
                direct(command(0.1))  # nothing went now: the rest waits for the loop
                old.closing = True  # and the link goes before the loop's write

        await asyncio.to_thread(take_then_lose_the_link)
        assert velocity(0.1) not in old.sent + old.written
        old.close()
        await until(lambda: len(connector.opened["control"]) == 2 and host.control.connected)
        new = connector.opened["control"][1]
        await asyncio.sleep(0.01)
        assert velocity(0.1) not in new.sent + new.written

    hosted(test)


def test_an_input_without_bytes_writes_nothing_but_the_loop_still_publishes_its_report() -> None:
    """A refused command produced no bytes, but a report to publish."""

    async def test(host: GatewayHost, connector: Connector, output: RecordingOutput) -> None:
        stream = connector.opened["control"][0]
        stream.calls = 0
        assert await take(host, ("default", b"not json"))
        assert stream.calls == 0
        await until(lambda: any(report.key.endswith("cmd_vel") for report in output.of(ErrorReport)))

    hosted(test)


def test_no_direct_take_once_the_host_stopped_and_its_loop_closed() -> None:
    settings = GatewaySettings(cmd_timeout=0.0, unsafe_start_released=True)
    settings.check()
    host = GatewayHost(settings, Connector(), RecordingOutput(), MemoryLatchStore())

    async def serve_briefly() -> None:
        stop = asyncio.Event()
        run = asyncio.create_task(host.run(stop))
        await until(lambda: host.control.connected)
        stop.set()
        await run

    asyncio.run(serve_briefly())  # its loop is closed now
    direct = host.direct(host.core.on_cmd_vel)
    with host.lock:
        assert direct(command(0.1)) is False, "a stopped host takes nothing directly"
    host.driver.schedule(lambda: None)  # the loop is gone: nothing to schedule on, nothing raised
