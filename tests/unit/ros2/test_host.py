"""A ROS 2 view nobody watches costs nothing (issue #29): no stream followed, nothing encoded, until a subscriber appears.

The core on a fake clock, then the node's real Zenoh edge on an isolated session, where Zenoh's own matching
status says whether anyone subscribes."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest
import zenoh
from helpers import wait_for

from blackmetal.ros2.core import Ros2Core
from blackmetal.ros2.host import Ros2Host
from blackmetal.ros2.messages import RosCodec
from blackmetal.ros2.settings import Ros2Settings
from blackmetal.ros2.zenoh_edge import Ros2Zenoh
from blackmetal.schemas import Keys, Pose, WheelImpulses, encode
from unit.ros2.test_services import make_core

#: The navigation's feedback is always followed: it keeps the action's goal states (nothing flows while no goal runs).
NAV = frozenset({"nav_feedback"})


@pytest.fixture(scope="module")
def codec() -> RosCodec:
    return RosCodec()


def pose(stamp: float = 1.0) -> bytes:
    return encode(Pose(stamp=stamp, x=1.0, y=2.0, yaw=0.0, v=0.1, w=0.0))


@contextmanager
def serving(edge: Ros2Zenoh, host: Ros2Host) -> Iterator[asyncio.AbstractEventLoop]:
    """``host`` attached to ``edge`` and running on a loop of its own thread; stopped, and the edge closed, at the end."""
    loop = asyncio.new_event_loop()
    stop = asyncio.Event()
    thread = threading.Thread(target=loop.run_until_complete, args=(host.run(stop),), daemon=True)
    edge.attach(host, loop)
    thread.start()
    try:
        yield loop
    finally:
        loop.call_soon_threadsafe(stop.set)
        thread.join(5)
        edge.close()
        loop.close()


def test_nothing_is_followed_or_encoded_until_a_topic_is_watched(codec: RosCodec) -> None:
    core, out = make_core(codec)
    core.start()
    assert out.followed == [NAV]  # nobody watches: no pose, no impulses, no error reports (the navigation's feedback: always)
    core.on_pose(pose(), now=1.0)
    core.on_impulses(encode(WheelImpulses(seq=1, stamp=1.0, left=10, right=10)), now=1.0)
    core.tick(5.0)  # the diagnostics are due, and nobody subscribes to them
    assert [topic for topic, _ in out.ros_out] == []

    core.on_matched("odom", True, now=6.0)
    assert out.followed[-1] == NAV | {"pose"}
    core.on_pose(pose(2.0), now=6.1)
    assert [topic for topic, _ in out.ros_out] == ["odom"]  # /odom only: /tf is not watched
    core.on_matched("joint_states", True, now=6.2)
    core.on_matched("diagnostics", True, now=6.3)
    assert out.followed[-1] == NAV | {"pose", "impulses", "errors", "health"}
    core.tick(6.3)  # a new diagnostics watcher gets the statuses at once
    assert out.ros_out[-1][0] == "diagnostics"
    for topic in ("odom", "joint_states", "diagnostics"):
        core.on_matched(topic, False, now=7.0)
    assert out.followed[-1] == NAV
    count = len(out.ros_out)
    core.on_pose(pose(3.0), now=7.1)
    core.tick(9.0)
    assert len(out.ros_out) == count


def test_the_wheels_on_tf_need_the_impulses_and_tf_needs_the_poses(codec: RosCodec) -> None:
    from blackmetal.ros2.options import RobotModel, Wheel

    core, out = make_core(codec)
    core.options = type(core.options)(**{**{f: getattr(core.options, f) for f in core.options.__dataclass_fields__},
                                          "publish_tf": True,
                                          "robot": RobotModel("<robot/>", (), (Wheel("base_link", "l", 0.2), Wheel("base_link", "r", -0.2)))})  # fmt: skip
    core.start()
    core.on_matched("tf", True, now=1.0)
    assert out.followed[-1] == NAV | {"pose", "impulses"}


def test_the_real_edge_follows_poses_only_while_odom_has_a_subscriber(session: zenoh.Session, codec: RosCodec) -> None:
    keys = Keys()
    settings = Ros2Settings(tf=False)
    edge = Ros2Zenoh(session, settings, codec)
    core = Ros2Core(settings.options(edge.data_keys, edge.service_keys), keys, edge, codec)
    poses: list[float] = []
    original = core.on_pose

    def counted(payload: bytes, now: float) -> None:
        poses.append(now)
        original(payload, now)

    core.on_pose = counted  # type: ignore[method-assign]
    publisher = session.declare_publisher(keys.pose)
    odoms: list[Any] = []
    with serving(edge, Ros2Host(core)):
        wait_for(lambda: core.watched is not None and "pose" not in edge._followed, what="the node started, following nothing")
        for stamp in range(20):
            publisher.put(pose(float(stamp)))
        assert poses == []  # no pose subscriber: nothing ran in Python for them

        subscriber = session.declare_subscriber(edge.data_keys["odom"], lambda sample: odoms.append(sample))
        wait_for(lambda: "pose" in edge._followed, what="/odom's subscriber to make the node follow poses")

        def publish_and_count() -> int:
            publisher.put(pose(100.0))
            return len(odoms)

        wait_for(publish_and_count, what="/odom published while someone subscribes")
        subscriber.undeclare()
        wait_for(lambda: "pose" not in edge._followed, what="the poses unfollowed when the last subscriber left")
    publisher.undeclare()


def test_a_waiting_set_estop_follows_the_health_until_it_is_answered(codec: RosCodec) -> None:
    from blackmetal.ros2.naming import attachment
    from unit.ros2.test_services import GID, health, set_bool_request

    core, out = make_core(codec)
    core.start()
    core.calls.on_service_request("set_estop", 1, set_bool_request(True), attachment(1, 1, GID), now=1.0)
    assert out.followed[-1] == NAV | {"health"}
    core.on_health(health(estop=True), now=1.05)
    assert 1 in out.replies and out.followed[-1] == NAV


def test_a_stamped_commands_age_limit_is_the_gateways_cmd_timeout_parameter(codec: RosCodec) -> None:
    from blackmetal.schemas import GatewayParams, Param

    core, out = make_core(codec)  # its wall clock: 1_700_000_000.0
    core.calls.on_params(encode(GatewayParams(stamp=1.0, params=[Param("cmd_timeout", "double", 0.2, min=0.0, max=10.0)])), now=1.0)
    core.on_cmd_vel(codec.encode_twist(0.1, 0.0, stamp=1_700_000_000.0 - 0.3), now=1.0, stamped=True)
    assert out.forwarded == [] and "command timeout 0.2 s" in out.errors[-1].reason


def test_a_fleet_node_takes_the_followed_poses_from_a_ring_when_drained(session: zenoh.Session, codec: RosCodec) -> None:
    keys = Keys("fleet/r1")
    settings = Ros2Settings(tf=False, namespace="r1", prefix=keys.prefix)
    edge = Ros2Zenoh(session, settings, codec, fleet=True)
    core = Ros2Core(settings.options(edge.data_keys, edge.service_keys), keys, edge, codec)
    publisher = session.declare_publisher(keys.pose)
    odoms: list[Any] = []
    subscriber = session.declare_subscriber(edge.data_keys["odom"], lambda sample: odoms.append(sample))
    with serving(edge, Ros2Host(core, supervised=True)) as loop:
        wait_for(lambda: "pose" in edge._followed, what="/odom's subscriber to make the node follow poses")
        for stamp in range(5):
            publisher.put(pose(float(stamp + 1)))
        time.sleep(0.2)
        assert odoms == []  # the poses wait in the ring: no Python ran for them

        def drain() -> int:
            done = threading.Event()
            taken: list[int] = []
            loop.call_soon_threadsafe(lambda: (taken.append(edge.drain()), done.set()))
            done.wait(5)
            return taken[0]

        assert drain() == 5
        wait_for(lambda: len(odoms) == 5, what="five /odom from one drain")
    subscriber.undeclare()
    publisher.undeclare()
