"""A fleet odometry takes its impulse samples from Zenoh rings, drained by the loop (issue #29: no Python per sample on
Zenoh's threads); a bug in one robot's handling fails that robot alone. The real edge on an isolated session."""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Coroutine
from typing import Any

import pytest
import zenoh

from blackmetal.odometry_service.fleet import DRAIN_PERIOD_S, ROLE, fleet_settings
from blackmetal.odometry_service.settings import OdometrySettings
from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.fleet import FleetRobot
from blackmetal.runtime.service import Member, drain
from blackmetal.schemas import Pose, WheelImpulses, decode, encode


def robots() -> list[FleetRobot]:
    return [FleetRobot(i, f"r{i}", "127.0.0.1", 1, 2, f"fleet/r{i}") for i in (1, 2)]


START = time.time()


def two_robots_posing(session: zenoh.Session) -> tuple[list[Member[OdometrySettings]], dict[str, list[Pose]], list[Any]]:
    """r1 and r2's odometry members (not started), the poses each publishes, and the subscribers that collect them."""
    fleet = robots()
    burst = PutBurst(max_hold=math.inf)  # one for the fleet, as serve_fleet makes it; held to the end of each turn
    members = [Member(ROLE, r, s, session, burst) for r, s in zip(fleet, fleet_settings(OdometrySettings(), fleet), strict=True)]
    poses: dict[str, list[Pose]] = {"r1": [], "r2": []}
    subscribers = [
        session.declare_subscriber(
            f"fleet/{name}/pose", lambda sample, name=name: poses[name].append(decode(Pose, sample.payload.to_bytes()))
        )
        for name in poses
    ]
    return members, poses, subscribers


def run_then_undeclare(scenario: Coroutine[Any, Any, None], subscribers: list[Any]) -> None:
    try:
        asyncio.run(scenario)
    finally:
        for subscriber in subscribers:
            subscriber.undeclare()


def impulses(seq: int, left: int) -> bytes:
    return encode(WheelImpulses(seq=seq, stamp=START + 0.02 * seq, left=left, right=left, mono=0.02 * seq, source="gw-test"))


def test_samples_wait_in_the_ring_until_the_drain_and_a_failing_robot_fails_alone(session: zenoh.Session) -> None:
    members, poses, subscribers = two_robots_posing(session)

    async def scenario() -> None:
        stop = asyncio.Event()
        for member in members:
            member.start()
        runs = [asyncio.ensure_future(member.run(stop)) for member in members]
        for seq in range(1, 6):
            for name in poses:
                session.put(f"fleet/{name}/wheels/impulses", impulses(seq, 10 * seq))
        await asyncio.sleep(0.2)
        assert poses == {"r1": [], "r2": []}  # nothing handled on Zenoh's threads: the samples wait in the rings
        for member in members:
            member.drain()
        assert len(members[0].burst) == 10  # the fleet's poses wait for the end of the loop's turn, put back to back
        for _ in range(100):
            if all(len(p) == 5 for p in poses.values()):
                break
            await asyncio.sleep(0.02)
        assert [len(p) for p in poses.values()] == [5, 5]

        def broken(payload: bytes) -> None:
            raise RuntimeError("a bug in r1's handling")

        assert members[0].host is not None
        members[0].host.on_impulses = broken  # type: ignore[method-assign]
        for name in poses:
            session.put(f"fleet/{name}/wheels/impulses", impulses(6, 60))
        await asyncio.sleep(0.2)
        for member in members:
            member.drain()
        with pytest.raises(RuntimeError, match="r1's handling"):
            await asyncio.wait_for(runs[0], 5)  # the supervisor gets it, and starts r1 again
        for _ in range(100):
            if len(poses["r2"]) == 6:
                break
            await asyncio.sleep(0.02)
        assert len(poses["r2"]) == 6 and not runs[1].done()  # r2 went on
        stop.set()
        await asyncio.wait_for(runs[1], 5)
        for member in members:
            member.close()

    run_then_undeclare(scenario(), subscribers)


def test_a_robot_whose_timers_fail_is_handed_to_the_supervisor(session: zenoh.Session) -> None:
    fleet = robots()[:1]
    member = Member(ROLE, fleet[0], fleet_settings(OdometrySettings(), fleet)[0], session, PutBurst())

    async def broken_run(stop: asyncio.Event) -> None:
        raise RuntimeError("a bug in r1's timers")

    async def scenario() -> None:
        member.start()
        assert member.host is not None
        member.host.run = broken_run  # type: ignore[method-assign]
        with pytest.raises(RuntimeError, match="r1's timers"):
            await asyncio.wait_for(member.run(asyncio.Event()), 5)
        member.close()

    asyncio.run(scenario())


def test_the_fleet_drain_takes_every_robots_samples_and_outlives_a_failing_robot(session: zenoh.Session) -> None:
    members, poses, subscribers = two_robots_posing(session)

    async def until(condition: object, what: str) -> None:
        for _ in range(250):
            if condition():  # type: ignore[operator]
                return
            await asyncio.sleep(0.02)
        raise AssertionError(f"timed out waiting for {what}: {[len(p) for p in poses.values()]}")

    async def scenario() -> None:
        stop = asyncio.Event()
        for member in members:
            member.start()
        runs = [asyncio.ensure_future(member.run(stop)) for member in members]
        draining = asyncio.ensure_future(drain(members, stop, DRAIN_PERIOD_S))
        for seq in range(1, 4):
            for name in poses:
                session.put(f"fleet/{name}/wheels/impulses", impulses(seq, 10 * seq))
        await until(lambda: [len(p) for p in poses.values()] == [3, 3], "three poses of each robot")

        def broken(payload: bytes) -> None:
            raise RuntimeError("a bug in r1's handling")

        assert members[0].host is not None
        members[0].host.on_impulses = broken  # type: ignore[method-assign]
        for seq in range(4, 6):
            for name in poses:
                session.put(f"fleet/{name}/wheels/impulses", impulses(seq, 10 * seq))
        with pytest.raises(RuntimeError, match="r1's handling"):
            await asyncio.wait_for(runs[0], 5)
        await until(lambda: len(poses["r2"]) == 5, "r2's poses after r1 failed")
        assert not draining.done() and not runs[1].done()
        stop.set()
        await asyncio.wait_for(asyncio.gather(draining, runs[1]), 5)
        for member in members:
            member.close()

    run_then_undeclare(scenario(), subscribers)
