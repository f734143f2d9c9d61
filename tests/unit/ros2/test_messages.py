"""ROS 2 messages both ways (:mod:`blackmetal.ros2.messages`): what the node writes reads back, what it reads is strict.

A decoding refusal is one sentence naming the type and what is wrong,
which the node reports on ``<prefix>/errors``. The hashes and the
parameter services are tests/unit/ros2/test_parameters.py's; the hot-path
bytes are test_cdr.py's.
"""

from __future__ import annotations

import math
import struct

import pytest

from blackmetal.ros2.messages import RosCodec
from blackmetal.ros2.ros_types import BOOL, DIAGNOSTIC_ARRAY, JOINT_STATE, SET_BOOL, STRING, TF_MESSAGE, TRIGGER, Frames, Transform
from blackmetal.runtime.diagnostics import Level, Status
from blackmetal.schemas import PayloadError, make_pose
from unit.ros2.test_services import encode_request


@pytest.fixture(scope="module")
def codec() -> RosCodec:
    return RosCodec()


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"\x00\x01", "invalid Twist: 2 bytes: a CDR message starts with a 4-byte encapsulation header"),
        (
            b"\x00\x03\x00\x00" + bytes(48),
            "invalid Twist: encapsulation header 00 03 00 00 is not plain CDR (expected 00 01 00 00, little-endian)",
        ),
        (b"\x00\x01\x00\x00" + bytes(20), "invalid Twist: not a valid CDR geometry_msgs/msg/Twist (24 bytes): "),
    ],
)
def test_a_payload_that_is_not_one_message_is_refused_in_one_sentence(codec: RosCodec, payload: bytes, reason: str) -> None:
    with pytest.raises(PayloadError) as refused:
        codec.twist(payload)
    assert str(refused.value).startswith(reason) and "\n" not in str(refused.value)
    assert refused.value.excerpt.startswith(payload[:4].hex(" "))


def test_a_big_endian_command_is_read_too(codec: RosCodec) -> None:
    twist = codec.twist(b"\x00\x00\x00\x00" + struct.pack(">6d", 0.5, 0.0, 0.0, 0.0, 0.0, -1.0))
    assert (twist.linear.x, twist.angular.z) == (0.5, -1.0)


@pytest.mark.parametrize("stamped", [False, True])
def test_a_command_that_is_not_finite_names_its_fields(codec: RosCodec, stamped: bool) -> None:
    payload = codec.encode_twist(math.nan, math.inf, stamp=1.0 if stamped else None)
    with pytest.raises(PayloadError, match=r"linear\.x, angular\.z must be finite numbers, got \[nan, inf\]"):
        codec.twist_stamped(payload) if stamped else codec.twist(payload)


def test_a_stamped_command_carries_its_stamp_and_a_zero_stamp_is_zero(codec: RosCodec) -> None:
    twist, stamp = codec.twist_stamped(codec.encode_twist(0.25, 0.5, stamp=1_700_000_000.5, frame_id="base_link"))
    assert (twist.linear.x, twist.angular.z, stamp) == (0.25, 0.5, 1_700_000_000.5)
    assert codec.twist_stamped(codec.encode_twist(0.25, 0.5, stamp=0.0))[1] == 0.0  # "no stamp": the age is not checked


def test_the_estop_and_the_service_requests_read_what_a_ros_client_sends(codec: RosCodec) -> None:
    assert codec.decode(codec.encode(BOOL, data=True), BOOL).data is True
    assert codec.decode(codec.encode(BOOL, data=False), BOOL).data is False
    assert codec.request(SET_BOOL, encode_request(codec, SET_BOOL, data=True)).data is True
    codec.request(TRIGGER, encode_request(codec, TRIGGER))
    with pytest.raises(PayloadError, match="invalid Bool"):
        codec.decode(codec.encode_twist(1.0, 0.0), BOOL)


def test_what_the_node_publishes_reads_back(codec: RosCodec) -> None:
    statuses = [
        Status(Level.ERROR, "n: robot link", "e-stop engaged", "robot", (("e-stop", "engaged"),)),
        Status(Level.OK, "n: odometry", "ok"),
    ]
    array = codec.decode(codec.diagnostics(1_700_000_000.25, statuses), DIAGNOSTIC_ARRAY)
    assert (array.header.stamp.sec, array.header.stamp.nanosec) == (1_700_000_000, 250_000_000)
    assert [(s.level, s.name, s.message, s.hardware_id) for s in array.status] == [
        (2, "n: robot link", "e-stop engaged", "robot"),
        (0, "n: odometry", "ok", ""),
    ]
    assert [(v.key, v.value) for v in array.status[0].values] == [("e-stop", "engaged")]

    tf = codec.decode(codec.transform(make_pose(5.0, 1.0, 2.0, math.pi / 2), Frames("r2/odom", "r2/base_footprint")), TF_MESSAGE)
    (one,) = tf.transforms
    assert (one.header.frame_id, one.child_frame_id, one.header.stamp.sec) == ("r2/odom", "r2/base_footprint", 5)
    assert (one.transform.translation.x, one.transform.translation.y) == (1.0, 2.0)
    assert (one.transform.rotation.z, one.transform.rotation.w) == pytest.approx((math.sqrt(0.5), math.sqrt(0.5)))
    wheels = codec.decode(codec.transforms(5.0, [Transform("a", "b", (0.0, 0.1, 0.0)), Transform("a", "c", (0.0, -0.1, 0.0))]), TF_MESSAGE)
    assert [(t.child_frame_id, t.transform.translation.y, t.transform.rotation.w) for t in wheels.transforms] == [
        ("b", 0.1, 1.0),
        ("c", -0.1, 1.0),
    ]

    joints = codec.decode(codec.joint_state(5.0, ["l", "r"], [1.0, 2.0], [0.5, -0.5]), JOINT_STATE)
    assert (list(joints.name), list(joints.position), list(joints.velocity), len(joints.effort)) == (["l", "r"], [1.0, 2.0], [0.5, -0.5], 0)
    assert codec.decode(codec.encode(STRING, data="<robot/>"), STRING).data == "<robot/>"
    response = codec.decode(codec.response(SET_BOOL, success=False, message="why"), f"{SET_BOOL}_Response")
    assert (response.success, response.message) == (False, "why")
