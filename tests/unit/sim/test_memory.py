"""The in-memory connector: the simulator's own handlers serve a pipe, and refuse once the server closed."""

from __future__ import annotations

import asyncio

import pytest

from blackmetal import wire
from blackmetal.sim.memory import MemoryConnector
from blackmetal.sim.physics import SimRobot
from blackmetal.sim.server import SimServer
from blackmetal.wire import CommandCode, LogReport, ReplyDecoder, SpeedReading, StatusReply


def test_control_and_log_ports_over_memory() -> None:
    async def scenario() -> list[object]:
        server = SimServer(SimRobot(), log_interval=0.01)
        connector = MemoryConnector(server)
        assert connector.describe("control") == "memory:control"
        replies: list[object] = []
        decoder = ReplyDecoder()
        control = await connector.open("control")
        log = await connector.open("log")
        pumps = [asyncio.ensure_future(s.pump(lambda data: replies.extend(decoder.feed(data)))) for s in (control, log)]
        control.write(wire.encode_request(wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY)))
        for _ in range(200):
            if any(isinstance(r, LogReport) for r in replies) and any(isinstance(r, SpeedReading) for r in replies):
                break
            await asyncio.sleep(0.01)
        await server.close()
        with pytest.raises(ConnectionRefusedError, match="not listening"):
            await connector.open("control")
        await asyncio.wait(pumps, timeout=1.0)
        return replies

    replies = asyncio.run(scenario())
    assert LogReport(1, 1) in replies
    assert [type(r) for r in replies if not isinstance(r, LogReport)] == [StatusReply, SpeedReading]
