"""The simulator's TCP ports: a control client served, a new one taking over, log reports, a busy port named."""

from __future__ import annotations

import asyncio

import pytest

from blackmetal import wire
from blackmetal.sim.physics import SimRobot
from blackmetal.sim.server import SimServer
from blackmetal.wire import CommandCode, LogReport, ReplyDecoder, StatusReply


async def read_replies(reader: asyncio.StreamReader, count: int) -> list[object]:
    decoder = ReplyDecoder()
    replies: list[object] = []
    while len(replies) < count:
        data = await asyncio.wait_for(reader.read(4096), 5.0)
        assert data, "the simulator closed the connection"
        replies.extend(decoder.feed(data))
    return replies


def test_a_new_control_client_takes_over_and_log_clients_get_reports() -> None:
    async def scenario() -> None:
        robot = SimRobot()
        server = SimServer(robot, control_port=0, log_port=0, log_interval=0.01)
        await server.start()
        try:
            assert server.control_port and server.log_port
            first_reader, first = await asyncio.open_connection("127.0.0.1", server.control_port)
            first.write(wire.encode_request(wire.simple(CommandCode.PREPARE_WHEEL_CONTROLLER)))
            (status,) = await read_replies(first_reader, 1)
            assert isinstance(status, StatusReply) and status.ok
            second_reader, second = await asyncio.open_connection("127.0.0.1", server.control_port)
            second.write(wire.encode_request(wire.simple(CommandCode.PREPARE_WHEEL_CONTROLLER)))
            assert isinstance((await read_replies(second_reader, 1))[0], StatusReply)
            assert await asyncio.wait_for(first_reader.read(), 5.0) == b""  # the old client was closed
            assert robot.counters["prepare"] == 2
            log_reader, log = await asyncio.open_connection("127.0.0.1", server.log_port)
            assert (await read_replies(log_reader, 2))[:2] == [LogReport(1, 1), LogReport(1, 1)]
            for writer in (second, log):
                writer.close()
        finally:
            await server.close()
        assert server.closed

    asyncio.run(scenario())


def test_a_port_in_use_is_named_with_what_to_do() -> None:
    async def scenario() -> None:
        taken = SimServer(SimRobot(), control_port=0, log_port=0)
        await taken.start()
        try:
            clash = SimServer(SimRobot(), control_port=0, log_port=taken.log_port)
            with pytest.raises(OSError, match=r"the log port\): the port is in use .* --log-port PORT"):
                await clash.start()
        finally:
            await taken.close()

    asyncio.run(scenario())
