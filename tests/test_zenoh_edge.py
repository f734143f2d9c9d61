"""The Zenoh edge's own lifecycle: what it declares goes when it closes, and its pump threads end with it.

One in-process peer session, no endpoints: nothing leaves the process.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator

import pytest
import zenoh
from helpers import wait_for

from blackmetal.runtime.edge import PUMP_JOIN_S, Handover, ZenohEdge


@pytest.fixture
def session() -> Iterator[zenoh.Session]:
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    conf.insert_json5("listen/endpoints", "[]")
    with zenoh.open(conf) as opened:
        yield opened


def _matching(publisher: zenoh.Publisher) -> bool:
    """Whether a subscriber matches (the stubs say bool; zenoh 1.x returns a MatchingStatus)."""
    status = publisher.matching_status
    return bool(getattr(status, "matching", status))


def _pumps() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("pump ")]


def test_closing_the_edge_ends_its_pumps_and_undeclares_their_subscribers(session: zenoh.Session) -> None:
    """A pump blocked on its subscriber must wake and end when the edge closes.

    It once waited on the subscriber itself, which kept the subscriber borrowed:
    ``undeclare()`` failed, the pump stayed inside Zenoh, and at exit CPython
    ended that thread mid-unwind, aborting the gateway ("FATAL: exception not rethrown").
    """
    loop = asyncio.new_event_loop()
    try:
        received: list[tuple[str, bytes]] = []
        edge = ZenohEdge(session)
        edge.pumped("edge/test/cmd_vel/*", received.append, Handover(loop))
        publisher = session.declare_publisher("edge/test/cmd_vel/nav")
        publisher.put(b"first")
        wait_for(lambda: received, what="the pumped sample")
        assert received == [("nav", b"first")]
        assert _matching(publisher)
        assert len(_pumps()) == 1

        edge.close()
        assert not _pumps(), f"pump threads still running {PUMP_JOIN_S} s after close: {_pumps()}"
        assert not _matching(publisher), "the pumped subscriber is still declared"
    finally:
        loop.close()
