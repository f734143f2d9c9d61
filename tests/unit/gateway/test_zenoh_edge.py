"""The gateway's Zenoh edge: its input table wires each key to its core method, and its outputs go to their keys.

One in-process peer session, no endpoints: nothing leaves the process. The
gateway's host is not serving (no robot), so every input waits for its loop,
and each command is refused for the link that is down, which shows it
reached the core by its key.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh
from helpers import MemoryLatchStore, wait_for

from blackmetal.gateway.estop import EStopInput
from blackmetal.gateway.host import GatewayHost
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.gateway.zenoh_edge import GatewayZenoh, _estop_batch
from blackmetal.schemas import ErrorReport, GatewayHealth, Keys, MoveState, WheelMoveReply, WheelPosition, decode
from blackmetal.transport import TcpConnector

PREFIX = "edge/gw"


def test_a_storms_pump_hands_over_the_first_engage_and_the_newest_state() -> None:
    on, off = EStopInput(False, True), EStopInput(True, False)
    assert _estop_batch([off, on, off, on, off]) == [on, off], "an ON is never lost behind a newer release"
    assert _estop_batch([off, on, off, on]) == [on], "the newest engages: nothing older counts"
    assert _estop_batch([off, off]) == [off]


class Edge:
    """A gateway's edge attached to a host that does not serve, on a running loop of its own."""

    def __init__(self, session: zenoh.Session) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.keys = Keys(PREFIX)
        self.edge = GatewayZenoh(session, self.keys)
        settings = GatewaySettings(prefix=PREFIX, source=["default:50", "nav:60"], unsafe_start_released=True)
        settings.check()
        self.host = GatewayHost(settings, TcpConnector("127.0.0.1", 9, 9), self.edge.publish, MemoryLatchStore())
        self.reports: list[ErrorReport] = []
        self.errors = session.declare_subscriber(self.keys.errors, lambda s: self.reports.append(decode(ErrorReport, s.payload.to_bytes())))
        self.intake = self.edge.attach(self.host, self.loop)

    def reasons(self) -> list[str]:
        return [report.reason for report in self.reports]

    def close(self) -> None:
        self.errors.undeclare()
        done = threading.Event()
        self.loop.call_soon_threadsafe(lambda: (self.edge.close(), done.set()))
        assert done.wait(10)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
        self.loop.close()


@pytest.fixture
def edge(session: zenoh.Session) -> Iterator[Edge]:
    made = Edge(session)
    yield made
    made.close()


def test_each_command_key_reaches_the_core_as_its_source(edge: Edge, session: zenoh.Session) -> None:
    for key in (f"{PREFIX}/cmd_vel", f"{PREFIX}/cmd_vel/nav"):
        session.put(key, b'{"linear":{"x":0.1}}')
    wait_for(lambda: sum("link is down" in reason for reason in edge.reasons()) == 2, what="both commands refused by the core")
    assert {report.key for report in edge.reports} == {edge.keys.cmd_vel_of("default"), edge.keys.cmd_vel_of("nav")}


def test_a_source_nobody_configured_is_refused_by_name(edge: Edge, session: zenoh.Session) -> None:
    session.put(f"{PREFIX}/cmd_vel/intruder", b'{"linear":{"x":0.1}}')
    wait_for(lambda: any("unknown command source 'intruder'" in reason for reason in edge.reasons()), what="the refusal")


def test_an_estop_is_read_where_it_enters_and_engages_the_core(edge: Edge, session: zenoh.Session) -> None:
    session.put(edge.keys.estop, b"true")
    wait_for(lambda: edge.host.health().estop, what="the e-stop engaged")


def test_health_is_answered_from_the_core(edge: Edge, session: zenoh.Session) -> None:
    def health() -> list[Any]:
        return [decode(GatewayHealth, reply.ok.payload.to_bytes()) for reply in session.get(edge.keys.health, timeout=2) if reply.ok]

    replies = health()
    assert len(replies) == 1 and replies[0].source == edge.host.core.run_token


def test_a_position_move_is_answered_by_the_core_and_its_progress_has_its_key(edge: Edge, session: zenoh.Session) -> None:
    replies = [
        reply.ok.payload.to_bytes() for reply in session.get(edge.keys.wheels_move, payload=b'{"left":1,"right":1}', timeout=2) if reply.ok
    ]
    assert len(replies) == 1
    answer = decode(WheelMoveReply, replies[0])
    assert not answer.accepted and answer.reason.startswith("position moves are off on this gateway")
    wait_for(lambda: any(report.key == edge.keys.wheels_move for report in edge.reports), what="the refusal reported")
    seen: list[bytes] = []
    listener = session.declare_subscriber(edge.keys.wheels_position, lambda sample: seen.append(sample.payload.to_bytes()))
    try:
        position = WheelPosition(1.0, "ab" * 16, "nav", MoveState.DONE, 1, -1, 0, 0, 1, -1, 0.5)
        wait_for(lambda: edge.edge.publish(position) or bool(seen), what="the progress on wheels/position")
        assert decode(WheelPosition, seen[0]) == position
    finally:
        listener.undeclare()
