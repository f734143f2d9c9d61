"""A fleet's telemetry puts wait for the end of the loop's turn and then all go, in order (issue #29: Zenoh batches
puts made back to back). The real publishers, on an isolated session."""

from __future__ import annotations

import asyncio
import math
import threading
from collections.abc import Callable, Coroutine
from typing import Any

import pytest
import zenoh

from blackmetal.gateway.fleet import ROLE as GATEWAY
from blackmetal.gateway.fleet import fleet_settings as gateway_fleet_settings
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.gateway.zenoh_edge import GatewayZenoh
from blackmetal.odometry_service.zenoh_edge import OdometryZenoh
from blackmetal.ros2.naming import parse_attachment
from blackmetal.ros2.zenoh_edge import _RosPublisher
from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.fleet import FleetRobot
from blackmetal.runtime.service import Member
from blackmetal.schemas import ErrorReport, Keys, WheelImpulses, decode, encode, make_pose

Run = Callable[[Coroutine[Any, Any, None]], None]


def collect(session: zenoh.Session, key: str) -> tuple[list[tuple[str, bytes]], threading.Condition, Any]:
    got: list[tuple[str, bytes]] = []
    arrived = threading.Condition()

    def on_sample(sample: zenoh.Sample) -> None:
        with arrived:
            got.append((str(sample.key_expr), sample.payload.to_bytes()))
            arrived.notify_all()

    return got, arrived, session.declare_subscriber(key, on_sample)


def test_puts_wait_for_the_end_of_the_turn_then_all_go_in_order(session: zenoh.Session, run_loop: Run) -> None:
    got, arrived, subscriber = collect(session, "burst/**")
    a, b = session.declare_publisher("burst/a"), session.declare_publisher("burst/b")
    burst = PutBurst()

    async def scenario() -> None:
        for i in range(3):
            burst.put(a, b"a%d" % i)
            burst.put(b, b"b%d" % i)
        assert len(burst) == 6
        with arrived:
            assert not arrived.wait_for(lambda: got, timeout=0.2)  # nothing put within the turn
        await asyncio.sleep(0)  # the turn ends
        assert len(burst) == 0
        burst.put(a, b"a3")  # a new burst, flushed at the end of the next turn
        await asyncio.sleep(0)

    try:
        run_loop(scenario())
        with arrived:
            assert arrived.wait_for(lambda: len(got) == 7, timeout=10), got
        assert [payload for key, payload in got if key == "burst/a"] == [b"a0", b"a1", b"a2", b"a3"]
        assert [payload for key, payload in got if key == "burst/b"] == [b"b0", b"b1", b"b2"]
    finally:
        subscriber.undeclare()


def test_a_put_refused_by_zenoh_is_dropped_and_the_rest_still_go(session: zenoh.Session, run_loop: Run) -> None:
    """A robot restarted after a bug closes its edge: its sample still held is dropped, the other robots' are not."""
    got, arrived, subscriber = collect(session, "burst/**")
    gone, kept = session.declare_publisher("burst/gone"), session.declare_publisher("burst/kept")
    burst = PutBurst()

    async def scenario() -> None:
        burst.put(gone, b"lost")
        burst.put(kept, b"one")
        gone.undeclare()
        burst.put(kept, b"two")
        await asyncio.sleep(0)

    try:
        run_loop(scenario())
        with arrived:
            assert arrived.wait_for(lambda: len(got) == 2, timeout=10), got
        assert got == [("burst/kept", b"one"), ("burst/kept", b"two")]
        assert burst.refused == 1
    finally:
        subscriber.undeclare()


def test_a_put_off_the_loop_is_refused_at_once(session: zenoh.Session, run_loop: Run) -> None:
    """Only the loop holds puts: a Zenoh thread or a test without a loop gets an error, not a put that never leaves,
    also while the loop holds some."""
    with pytest.raises(RuntimeError, match="no running event loop"):
        PutBurst().put(None, b"x")  # type: ignore[arg-type]
    publisher = session.declare_publisher("burst/a")
    burst = PutBurst()
    errors: list[BaseException] = []

    def off_the_loop() -> None:
        try:
            burst.put(publisher, b"from a Zenoh thread")
        except RuntimeError as exc:
            errors.append(exc)

    async def scenario() -> None:
        burst.put(publisher, b"held")
        thread = threading.Thread(target=off_the_loop)
        thread.start()
        thread.join(10)
        assert len(errors) == 1 and len(burst) == 1

    run_loop(scenario())


def test_a_put_held_for_max_hold_goes_at_once_with_those_before_it(session: zenoh.Session, run_loop: Run) -> None:
    """A turn that handles many robots does not keep the first one's sample for all of it."""
    got, arrived, subscriber = collect(session, "burst/**")
    a = session.declare_publisher("burst/a")
    burst = PutBurst(max_hold=0.0)

    async def scenario() -> None:
        burst.put(a, b"first")
        assert len(burst) == 1
        burst.put(a, b"second")  # the first has waited max_hold: both go now, within the turn
        assert len(burst) == 0
        with arrived:
            assert arrived.wait_for(lambda: len(got) == 2, timeout=10), got

    try:
        run_loop(scenario())
        assert [payload for _, payload in got] == [b"first", b"second"]
    finally:
        subscriber.undeclare()


def test_the_fleet_edges_hold_their_telemetry_and_never_an_error(session: zenoh.Session, run_loop: Run) -> None:
    """A fleet gateway's impulses, a fleet odometry's poses and a ROS node's volatile topic wait in the burst, with
    their rmw_zenoh attachment; an error report goes at once."""
    got, arrived, subscriber = collect(session, "t/**")
    attachments: list[bytes] = []

    def on_ros(sample: zenoh.Sample) -> None:
        with arrived:  # the same condition: a wait below covers both subscribers
            attachments.append(sample.attachment.to_bytes() if sample.attachment is not None else b"")
            arrived.notify_all()

    ros = session.declare_subscriber("t/ros/odom", on_ros)
    burst = PutBurst(max_hold=10.0)  # a loaded host may take over 1 ms between these puts: what is held here is the point
    gateway = GatewayZenoh(session, Keys("t/gw"), burst=burst)
    odometry = OdometryZenoh(session, Keys("t/odo"), burst=burst)
    node = _RosPublisher(session.declare_publisher("t/ros/odom"), b"g" * 16, burst)
    impulses = WheelImpulses(seq=1, stamp=1.0, left=2, right=3, mono=1.0, source="test")

    async def scenario() -> None:
        gateway.publish(impulses)
        odometry.publish(make_pose(1.0, 0.5, 0.25, 0.1))
        node.put(b"cdr")
        gateway.publish(ErrorReport(stamp=1.0, source="gateway", key="t/gw/cmd_vel", reason="not held"))
        assert len(burst) == 3
        with arrived:
            assert arrived.wait_for(lambda: len(got) == 1, timeout=10), got  # the error alone, before the turn ends
        assert got[0][0] == "t/gw/errors"
        await asyncio.sleep(0)

    try:
        run_loop(scenario())
        with arrived:
            assert arrived.wait_for(lambda: len(got) == 4 and attachments, timeout=10), (got, attachments)
        keys = [key for key, _ in got]
        assert keys == ["t/gw/errors", Keys("t/gw").impulses, Keys("t/odo").pose, "t/ros/odom"]
        assert decode(WheelImpulses, got[1][1]) == impulses and got[1][1] == encode(impulses)
        sequence, _, gid = parse_attachment(attachments[0])
        assert (sequence, gid) == (1, b"g" * 16)
    finally:
        ros.undeclare()
        subscriber.undeclare()
        gateway.close()
        odometry.close()


def test_a_fleet_gateways_robots_share_the_fleets_burst(session: zenoh.Session, run_loop: Run) -> None:
    """What ``gateway --fleet`` builds for each robot holds its impulses in the one burst the fleet flushes."""
    robots = [FleetRobot(i, f"r{i}", "127.0.0.1", 1, 2, f"fleet/r{i}") for i in (1, 2)]
    burst = PutBurst(max_hold=math.inf)
    members = [
        Member(GATEWAY, r, s, session, burst) for r, s in zip(robots, gateway_fleet_settings(GatewaySettings(), robots), strict=True)
    ]
    impulses = WheelImpulses(seq=1, stamp=1.0, left=2, right=3, mono=1.0, source="test")

    async def scenario() -> None:
        for member in members:
            edge = member.start().edge
            assert edge is not None
            edge.publish(impulses)
        assert len(burst) == 2  # not yet put: the fleet's one burst holds both robots' samples
        await asyncio.sleep(0)
        assert len(burst) == 0

    try:
        run_loop(scenario())
    finally:
        for member in members:
            member.close()
