"""The hot-path CDR of :mod:`blackmetal.ros2.cdr`: commands read straight from their bytes, ``/odom`` written straight.

The bytes here are laid out by hand from the IDL (little-endian CDR, each
primitive aligned to its size after the 4-byte header), independently of
both cdr.py and rosbags; rosbags then reads what cdr.py wrote. The property
tests that hold both paths equal on random values live beside the edge that
uses them (tests/unit/ros2/test_zenoh_edge.py).
"""

from __future__ import annotations

import struct

import pytest

from blackmetal.ros2 import cdr
from blackmetal.ros2.messages import RosCodec
from blackmetal.ros2.ros_types import ODOMETRY, Frames
from blackmetal.schemas import make_pose

SIX = (0.5, -0.1, 0.0, 0.0, 0.25, 1.5)
LE = b"\x00\x01\x00\x00"


@pytest.fixture(scope="module")
def codec() -> RosCodec:
    return RosCodec()


def stamped(sec: int, nanosec: int, frame_id: bytes, values: tuple[float, ...] = SIX) -> bytes:
    """geometry_msgs/TwistStamped as the IDL lays it out: stamp, frame_id (length with its NUL), padding to 8, six doubles."""
    body = struct.pack("<iII", sec, nanosec, len(frame_id) + 1) + frame_id + b"\x00"
    return LE + body + b"\x00" * (-len(body) % 8) + struct.pack("<6d", *values)


def test_rmw_zenohs_twist_is_read_straight_and_anything_else_is_left_to_rosbags() -> None:
    twist = LE + struct.pack("<6d", *SIX)
    assert cdr.twist_le(twist) == SIX
    assert cdr.twist_le(b"\x00\x00\x00\x00" + struct.pack(">6d", *SIX)) is None  # big-endian
    assert cdr.twist_le(twist + b"\x00") is None and cdr.twist_le(twist[:-1]) is None  # not exactly one Twist
    assert cdr.twist_le(b"") is None


@pytest.mark.parametrize("frame_id", [b"", b"b", b"base_lin", b"base_link", b"odom/with/a/long/frame_name"])
def test_a_stamped_command_is_read_at_the_padding_its_frame_id_gives(codec: RosCodec, frame_id: bytes) -> None:
    payload = stamped(1_700_000_000, 250_000_000, frame_id)
    assert payload == codec.encode_twist(0.0, 0.0, 1_700_000_000.25, frame_id.decode())[:-48] + struct.pack("<6d", *SIX)
    assert cdr.twist_stamped_le(payload) == (1_700_000_000, 250_000_000, SIX)


@pytest.mark.parametrize(
    "payload",
    [
        pytest.param(stamped(1, 2, b"base")[:-1], id="a byte short"),
        pytest.param(stamped(1, 2, b"base") + b"\x00" * 8, id="trailing bytes"),
        pytest.param(b"\x00\x00" + stamped(1, 2, b"base")[2:], id="big-endian"),
        pytest.param(stamped(1, 2, b"\xff\xfe"), id="frame_id not UTF-8"),
        pytest.param(stamped(1, 2, b"base").replace(b"base\x00", b"basex"), id="frame_id not NUL-terminated"),
        pytest.param(LE + struct.pack("<iII", 1, 2, 0) + struct.pack("<6d", *SIX), id="zero length"),
        pytest.param(LE + struct.pack("<iII", 1, 2, 2**31) + struct.pack("<6d", *SIX), id="length past the end"),
    ],
)
def test_a_stamped_command_that_does_not_add_up_is_left_to_rosbags(payload: bytes) -> None:
    assert cdr.twist_stamped_le(payload) is None


@pytest.mark.parametrize(("odom", "base"), [("odom", "base_footprint"), ("", ""), ("r2/odom", "r2/base_footprint"), ("ödom", "b")])
def test_odom_written_straight_reads_back_with_rosbags(codec: RosCodec, odom: str, base: str) -> None:
    pose = make_pose(1_700_000_000.125, 1.5, -2.0, 0.75, v=0.3, w=-0.2)
    pose_covariance, twist_covariance = [float(i) for i in range(36)], [float(-i) for i in range(36)]
    frames = Frames(odom, base)
    payload = cdr.odometry(pose, cdr.odometry_frames(frames), pose_covariance, twist_covariance)
    message = codec.store.deserialize_cdr(payload, ODOMETRY)
    assert (message.header.stamp.sec, message.header.stamp.nanosec) == (1_700_000_000, 125_000_000)
    assert (message.header.frame_id, message.child_frame_id) == (odom, base)
    position, q = message.pose.pose.position, message.pose.pose.orientation
    assert (position.x, position.y, position.z) == (1.5, -2.0, 0.0)
    assert (q.x, q.y, q.z, q.w) == (pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w)
    assert (message.twist.twist.linear.x, message.twist.twist.angular.z) == (0.3, -0.2)  # in base_footprint: no sideways speed
    assert list(message.pose.covariance) == pose_covariance and list(message.twist.covariance) == twist_covariance
    assert payload == codec.odometry(pose, frames, pose_covariance, twist_covariance)  # the codec writes through here
