"""The fleet's member, supervisor and drain (blackmetal.runtime.service), on fakes: no Zenoh, no sockets, milliseconds."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from typing import Any

import pytest

from blackmetal.runtime import service
from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.fleet import FleetRobot
from blackmetal.runtime.service import Member, Role, drain, supervise
from blackmetal.schemas import ErrorReport, Keys


@dataclass
class FakeEdge:
    keys: Keys
    follows: bool = True
    broken: bool = False
    drained: int = 0
    closed: bool = False
    errors: list[ErrorReport] = field(default_factory=list)

    looked: int = 0

    def following(self) -> bool:
        self.looked += 1
        return self.follows

    def drain(self) -> None:
        if self.broken:
            raise RuntimeError("a bug in this robot's handling")
        self.drained += 1

    def publish(self, message: ErrorReport) -> None:
        self.errors.append(message)

    def close(self) -> None:
        self.closed = True


class FakeHost:
    def __init__(self, fails: bool = False) -> None:
        self.fails = fails

    async def run(self, stop: asyncio.Event) -> None:
        if self.fails:
            raise RuntimeError("a bug in its timers")
        await stop.wait()


def member(builds: list[FakeEdge], *, fails: int = 0, follows: bool = True) -> Member[Any]:
    """A member whose first ``fails`` builds fail at once; every edge it builds goes into ``builds``."""

    def build(m: Member[Any]) -> tuple[FakeEdge, FakeHost]:
        edge = FakeEdge(Keys(m.robot.prefix), follows=follows)
        builds.append(edge)
        return edge, FakeHost(fails=len(builds) <= fails)

    role = Role("test", build, "test of {robot} failed ({exc!r}); again in {pause:g} s", "health")
    return Member(role, FleetRobot(1, "r1", "127.0.0.1", 1, 2, "fleet/r1"), object(), None, PutBurst())


def test_a_member_that_fails_is_reported_on_its_key_and_built_again(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(service, "RESTART_FIRST_S", 0.01)
    builds: list[FakeEdge] = []
    m = member(builds, fails=2)

    async def scenario() -> None:
        stop = asyncio.Event()
        task = asyncio.ensure_future(supervise(m, stop))
        while len(builds) < 3:
            await asyncio.sleep(0.005)
        stop.set()
        await asyncio.wait_for(task, 1)

    asyncio.run(scenario())
    assert len(builds) == 3 and all(edge.closed for edge in builds)
    reasons = [e.reason for edge in builds for e in edge.errors]
    assert reasons == [
        "test of robot 1 (id 'r1') failed (RuntimeError('a bug in its timers')); again in 0.01 s",
        "test of robot 1 (id 'r1') failed (RuntimeError('a bug in its timers')); again in 0.02 s",
    ]
    assert {(e.source, e.key) for edge in builds for e in edge.errors} == {("test", Keys("fleet/r1").health)}
    assert m.edge is None  # closed at the stop; a start builds anew


def test_a_drain_that_raises_fails_its_member_alone_and_an_idle_fleet_drains_seldom() -> None:
    builds: list[FakeEdge] = []
    good, bad, idle = member(builds), member(builds), member(builds, follows=False)

    async def scenario() -> None:
        stop = asyncio.Event()
        for m in (good, bad, idle):
            m.start()
        bad.edge.broken = True
        runs = [asyncio.ensure_future(m.run(stop)) for m in (good, bad)]
        assert [m.drain() for m in (good, bad, idle)] == [True, True, False]  # the idle one follows nothing
        with pytest.raises(RuntimeError, match="handling"):
            await asyncio.wait_for(runs[1], 1)
        assert not bad.drain()  # a failed member is not drained again
        assert not runs[0].done() and good.drain()
        stop.set()
        await asyncio.wait_for(runs[0], 1)

    asyncio.run(scenario())
    assert builds[0].drained == 2 and builds[2].drained == 0


def test_the_fleet_drain_looks_seldom_while_nobody_follows() -> None:
    builds: list[FakeEdge] = []
    idle, busy = member(builds, follows=False), member(builds)

    async def scenario(members: list[Member[Any]]) -> None:
        stop = asyncio.Event()
        for m in members:
            m.start()
        asyncio.get_running_loop().call_later(0.25, stop.set)
        await drain(members, stop, 0.005, 0.1)

    asyncio.run(scenario([idle]))
    assert builds[0].drained == 0 and builds[0].looked <= 4  # every 0.1 s, not every 5 ms
    asyncio.run(scenario([busy]))
    assert builds[1].drained >= 10  # every 5 ms while it follows
