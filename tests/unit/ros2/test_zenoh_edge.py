"""ROS ``/cmd_vel`` is taken and forwarded on Zenoh's thread (issue #28: one hop in line, no wake of the adapter's loop);
Twist, TwistStamped and Odometry read and written straight from and to their bytes, as rosbags reads and writes them.

The node's real Zenoh edge on an isolated session; its loop on a thread of the test."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
import zenoh
from helpers import wait_for
from hypothesis import given, settings
from hypothesis import strategies as st

from blackmetal.ros2.core import Ros2Core
from blackmetal.ros2.host import Ros2Host
from blackmetal.ros2.messages import RosCodec
from blackmetal.ros2.naming import CMD_VEL_STAMPED
from blackmetal.ros2.ros_types import ODOMETRY, TWIST, TWIST_STAMPED
from blackmetal.ros2.settings import Ros2Settings
from blackmetal.ros2.zenoh_edge import Ros2Zenoh
from blackmetal.schemas import ErrorReport, Keys, PayloadError, Twist, decode, stamp_parts


@pytest.fixture(scope="module")
def codec() -> RosCodec:
    return RosCodec()


class Node:
    """The adapter's node on ``session``, its loop running on a thread; records where each direct take ran."""

    def __init__(self, session: zenoh.Session, codec: RosCodec) -> None:
        self.keys = Keys()
        settings = Ros2Settings(tf=False)
        self.edge = Ros2Zenoh(session, settings, codec)
        core = Ros2Core(settings.options(self.edge.data_keys, self.edge.service_keys), self.keys, self.edge, codec)
        self.host = Ros2Host(core)
        self.direct: list[tuple[str, bool]] = []  # (thread name, taken)
        self.calls = 0  # direct takes begun: a take forwards its command before it is recorded
        make = self.host.direct

        def direct(stamped: bool = False) -> Callable[[bytes], bool]:
            take = make(stamped)

            def recorded(cdr: bytes) -> bool:
                self.calls += 1
                taken = take(cdr)
                self.direct.append((threading.current_thread().name, taken))
                return taken

            return take if stamped else recorded

        self.host.direct = direct  # type: ignore[method-assign]
        self.loop = asyncio.new_event_loop()
        self.stop = asyncio.Event()
        self.thread = threading.Thread(target=self.loop.run_until_complete, args=(self.host.run(self.stop),), name="node loop")
        self.edge.attach(self.host, self.loop)
        self.thread.start()

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self.stop.set)
        self.thread.join(5)
        self.edge.close()
        self.loop.close()


@pytest.fixture
def node(session: zenoh.Session, codec: RosCodec) -> Iterator[Node]:
    started = Node(session, codec)
    yield started
    started.close()


def listen(session: zenoh.Session, key: str) -> tuple[list[bytes], Any]:
    got: list[bytes] = []
    return got, session.declare_subscriber(key, lambda sample: got.append(bytes(sample.payload.to_bytes())))


def test_a_ros_command_is_forwarded_on_zenohs_thread_not_the_loop(session: zenoh.Session, node: Node, codec: RosCodec) -> None:
    commands, sub = listen(session, node.keys.cmd_vel_of("ros2"))
    ros = session.declare_publisher(node.edge.data_keys["cmd_vel"])
    wait_for(lambda: node.host.core.watched is not None, what="the node to start")
    for i in range(1, 6):
        ros.put(codec.encode_twist(0.1 * i, 0.0))
        wait_for(lambda i=i: len(commands) >= i, what=f"command {i} forwarded to the gateway's key")  # type: ignore[misc]
    assert [decode(Twist, c).linear.x for c in commands] == pytest.approx([0.1, 0.2, 0.3, 0.4, 0.5])
    assert node.direct and all(taken for _, taken in node.direct)
    assert {name for name, _ in node.direct}.isdisjoint({"node loop", threading.current_thread().name})
    sub.undeclare()
    ros.undeclare()


def test_while_the_loop_is_in_the_core_a_command_waits_for_it_and_none_is_lost(session: zenoh.Session, node: Node, codec: RosCodec) -> None:
    commands, sub = listen(session, node.keys.cmd_vel_of("ros2"))
    ros = session.declare_publisher(node.edge.data_keys["cmd_vel"])
    wait_for(lambda: node.host.core.watched is not None, what="the node to start")
    holding = threading.Event()
    release = threading.Event()

    def in_the_core() -> None:  # the loop busy in the core: it holds the lock
        with node.host.lock:
            holding.set()
            release.wait(5)

    node.loop.call_soon_threadsafe(in_the_core)
    assert holding.wait(5)
    ros.put(codec.encode_twist(0.25, 0.0))
    intake = node.edge._intakes[0]
    wait_for(lambda: intake.stats()["cmd_vel"][0] == 1, what="the command handed to the intake")
    time.sleep(0.2)  # what would have been forwarded directly has had ample time to arrive
    assert commands == []
    release.set()  # the loop drains what waited: the same command, handled there
    wait_for(lambda: commands, what="the command forwarded once the loop left the core")
    assert decode(Twist, commands[0]).linear.x == pytest.approx(0.25)
    assert node.direct == []  # the core was busy: no direct take, and the loop's drain takes none
    sub.undeclare()
    ros.undeclare()


def test_a_stale_stamped_command_is_left_to_the_loop_which_reports_it(session: zenoh.Session, node: Node, codec: RosCodec) -> None:
    commands, sub = listen(session, node.keys.cmd_vel_of("ros2"))
    errors, err_sub = listen(session, node.keys.errors)
    ros = session.declare_publisher(node.edge.data_keys[CMD_VEL_STAMPED])
    wait_for(lambda: node.host.core.watched is not None, what="the node to start")
    ros.put(codec.encode_twist(0.3, 0.0, stamp=time.time() - 30.0))
    wait_for(lambda: errors, what="the stale command reported on robot/errors")
    assert "older than the gateway's command timeout" in decode(ErrorReport, errors[0]).reason
    ros.put(codec.encode_twist(0.2, 0.0, stamp=time.time()))
    wait_for(lambda: commands, what="a fresh stamped command forwarded")
    assert [decode(Twist, c).linear.x for c in commands] == pytest.approx([0.2])
    for entity in (sub, err_sub, ros):
        entity.undeclare()


# ---- the command read straight from its bytes equals rosbags' reading, errors included

finite_or_not = st.floats(allow_nan=True, allow_infinity=True, width=64)


def _reference(codec: RosCodec, payload: bytes, stamped: bool) -> tuple[Any, float] | str:
    """rosbags' reading of the payload (the codec's slow path), or the reason it refuses it."""
    try:
        message = codec.decode(payload, TWIST_STAMPED if stamped else TWIST)
        twist = codec._twist(payload, message.twist if stamped else message)
    except PayloadError as exc:
        return exc.reason
    stamp = message.header.stamp.sec + message.header.stamp.nanosec * 1e-9 if stamped else 0.0
    return twist, stamp


def _fast(codec: RosCodec, payload: bytes, stamped: bool) -> tuple[Any, float] | str:
    try:
        return codec.twist_stamped(payload) if stamped else (codec.twist(payload), 0.0)
    except PayloadError as exc:
        return exc.reason


@settings(max_examples=120, deadline=None)
@given(
    values=st.tuples(*[finite_or_not] * 6),
    stamped=st.booleans(),
    sec=st.integers(-(2**31), 2**31 - 1),
    nanosec=st.integers(0, 2**32 - 1),
    frame_id=st.text(max_size=12),
    cut=st.integers(0, 90),
    flip=st.tuples(st.integers(0, 90), st.integers(0, 255)),
)
def test_a_command_read_from_its_bytes_is_what_rosbags_reads(
    codec: RosCodec,
    values: tuple[float, ...],
    stamped: bool,
    sec: int,
    nanosec: int,
    frame_id: str,
    cut: int,
    flip: tuple[int, int],
) -> None:
    lx, ly, lz, ax, ay, az = values
    linear, angular = codec.vector3(lx, ly, lz), codec.vector3(ax, ay, az)
    if stamped:
        header = codec.message(
            "std_msgs/msg/Header", stamp=codec.message("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec), frame_id=frame_id
        )
        payload = codec.encode(TWIST_STAMPED, header=header, twist=codec.message(TWIST, linear=linear, angular=angular))
    else:
        payload = codec.encode(TWIST, linear=linear, angular=angular)
    for candidate in (payload, payload[: len(payload) - cut % 9], _flipped(payload, *flip)):
        assert repr(_fast(codec, candidate, stamped)) == repr(_reference(codec, candidate, stamped))


def _flipped(payload: bytes, at: int, value: int) -> bytes:
    at %= len(payload)
    return payload[:at] + bytes([value]) + payload[at + 1 :]


def test_once_the_intake_is_closed_no_command_is_taken_directly(session: zenoh.Session, node: Node, codec: RosCodec) -> None:
    commands, sub = listen(session, node.keys.cmd_vel_of("ros2"))
    ros = session.declare_publisher(node.edge.data_keys["cmd_vel"])
    wait_for(lambda: node.host.core.watched is not None, what="the node to start")
    ros.put(codec.encode_twist(0.1, 0.0))
    wait_for(lambda: commands, what="a command forwarded while the node serves")
    wait_for(lambda: len(node.direct) == node.calls, what="a direct take in progress to be recorded")
    tried = len(node.direct)  # the first may have gone through the loop, busy starting
    node.edge._intakes[0].close()  # what the edge does first when it closes, before it undeclares the publisher
    ros.put(codec.encode_twist(0.2, 0.0))
    time.sleep(0.3)
    assert len(commands) == 1 and len(node.direct) == tried
    sub.undeclare()
    ros.undeclare()


frame_name = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=20)
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=50, deadline=None)
@given(
    stamp=st.floats(0, 2**31 - 1),  # builtin_interfaces/Time's sec is an int32
    x=finite,
    y=finite,
    yaw=st.floats(-10, 10),
    v=finite,
    w=finite,
    odom=frame_name,
    base=frame_name,
    pose_covariance=st.lists(finite, min_size=36, max_size=36),
    twist_covariance=st.lists(finite, min_size=36, max_size=36),
)
def test_odom_written_straight_is_what_rosbags_writes(
    codec: RosCodec,
    stamp: float,
    x: float,
    y: float,
    yaw: float,
    v: float,
    w: float,
    odom: str,
    base: str,
    pose_covariance: list[float],
    twist_covariance: list[float],
) -> None:
    from blackmetal.ros2.ros_types import Frames
    from blackmetal.schemas import make_pose

    pose = make_pose(stamp, x, y, yaw, v, w)
    frames = Frames(odom, base)
    fast = codec.odometry(pose, frames, pose_covariance, twist_covariance)
    assert fast == odometry_by_rosbags(codec, pose, frames, pose_covariance, twist_covariance)


def odometry_by_rosbags(codec: RosCodec, pose: Any, frames: Any, pose_covariance: Any, twist_covariance: Any) -> bytes:
    """:meth:`RosCodec.odometry` written by rosbags, field by field: the reference the fast writing is held to."""
    import numpy as np

    t, q = codec.store.types, pose.orientation
    vector = t["geometry_msgs/msg/Vector3"]
    sec, nanosec = stamp_parts(pose.stamp)
    message = t[ODOMETRY](
        header=t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frames.odom),
        child_frame_id=frames.base,
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=pose.x, y=pose.y, z=0.0),
                orientation=t["geometry_msgs/msg/Quaternion"](x=q.x, y=q.y, z=q.z, w=q.w),
            ),
            covariance=np.asarray(pose_covariance, dtype=np.float64),
        ),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t[TWIST](linear=vector(x=pose.v, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=pose.w)),
            covariance=np.asarray(twist_covariance, dtype=np.float64),
        ),
    )
    return bytes(codec.store.serialize_cdr(message, ODOMETRY))
