"""Schemas: what real clients send is accepted; hostile payloads get one clear error."""

from __future__ import annotations

import json
import math
from typing import Any

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from blackmetal.schemas import (
    MESSAGE_TYPES,
    ErrorReport,
    EStop,
    PayloadError,
    Pose,
    Twist,
    WheelImpulses,
    decode,
    encode,
    excerpt,
    json_schemas,
    make_pose,
    payload_bytes,
    wrap_angle,
)
from blackmetal.schemas.codec import MAX_PAYLOAD_BYTES


@pytest.mark.parametrize(
    "payload, linear_x, angular_z",
    [
        (b'{"linear":{"x":0.2}}', 0.2, 0.0),
        (b'{"linear":{"x":0.2}}\n', 0.2, 0.0),
        (b'  {"angular":{"z":-1.5}}\r\n\t', 0.0, -1.5),
        (b"{}", 0.0, 0.0),
        (b'{"linear":{"x":1,"y":0,"z":0},"angular":{"x":0,"y":0,"z":2}}', 1.0, 2.0),
        (b'\xef\xbb\xbf{"linear":{"x":0.1}}', 0.1, 0.0),
        ('{"linear":{"x":0.3}}', 0.3, 0.0),
        (bytearray(b'{"linear":{"x":0.3}}'), 0.3, 0.0),
    ],
)
def test_twist_accepts_what_clients_send(payload: bytes, linear_x: float, angular_z: float) -> None:
    twist = decode(Twist, payload)
    assert twist.linear.x == linear_x
    assert twist.angular.z == angular_z
    assert twist.linear.y == twist.linear.z == twist.angular.x == twist.angular.y == 0.0


@pytest.mark.parametrize(
    "payload, fragment",
    [
        (b"", "empty"),
        (b"   \n", "empty"),
        (b"hello", "not a JSON object"),
        (b"[1,2]", "not a JSON object"),
        (b"0.5", "not a JSON object"),
        (b'"x"', "not a JSON object"),
        (b"null", "not a JSON object"),
        (b'{"linear":{"x":NaN}}', "not valid JSON"),
        (b'{"linear":{"x":Infinity}}', "not valid JSON"),
        (b'{"linear":{"x":1e999}}', "not finite"),
        (b'{"linear":{"x":-1e400}}', "not finite"),
        (b'{"linear":{"x":"fast"}}', "Expected `float`, got `str`"),
        (b'{"linear":{"x":true}}', "Expected `float`, got `bool`"),
        (b'{"linear":[0.1,0,0]}', "Expected `object`, got `array`"),
        (b'{"linear":{"X":0.2}}', "unknown field `X`"),
        (b'{"speed":1}', "unknown field `speed`"),
        (b'{"linear":{"x":0.2}', "not valid JSON"),
        (b'{"linear":{"x":0.2}}{"linear":{"x":0.2}}', "not valid JSON"),
        (b"\xff\xfe{", "not a JSON object"),
        (b'{"linear":{"x":0.2}}' + b" " * MAX_PAYLOAD_BYTES, "larger than"),
        (b"{" + b"x" * (1024 * 1024), "larger than"),
    ],
)
def test_twist_rejects_hostile_payloads_with_a_reason(payload: bytes, fragment: str) -> None:
    with pytest.raises(PayloadError) as info:
        decode(Twist, payload)
    assert fragment in str(info.value)
    assert str(info.value).startswith("invalid Twist: ")
    assert len(info.value.excerpt) <= 80


def test_payload_error_is_a_value_error_with_a_printable_excerpt() -> None:
    with pytest.raises(ValueError) as info:
        decode(Twist, b'{"linear":{"x":"\x00\x1b[2J"}}')
    err = info.value
    assert isinstance(err, PayloadError)
    assert err.excerpt.isprintable()


def test_estop_requires_a_boolean() -> None:
    assert decode(EStop, b'{"engaged": true}\n').engaged is True
    assert decode(EStop, b'{"engaged":false}').engaged is False
    for bad in (b"{}", b'{"engaged":1}', b'{"engaged":"yes"}', b'{"engaged":null}'):
        with pytest.raises(PayloadError):
            decode(EStop, bad)


def test_wheel_impulses_round_trip_and_reject_bad_values() -> None:
    msg = WheelImpulses(seq=7, stamp=1700000000.25, left=150, right=-148)
    assert decode(WheelImpulses, encode(msg)) == msg
    with pytest.raises(PayloadError, match="seq"):
        decode(WheelImpulses, b'{"seq":-1,"stamp":1.0,"left":1,"right":1}')
    with pytest.raises(PayloadError, match="left"):
        decode(WheelImpulses, b'{"seq":1,"stamp":1.0,"left":1.5,"right":1}')
    with pytest.raises(PayloadError, match="stamp"):
        decode(WheelImpulses, b'{"seq":1,"left":1,"right":1}')
    # our own services tolerate fields added by a newer publisher
    assert decode(WheelImpulses, b'{"seq":1,"stamp":1.0,"left":1,"right":2,"extra":3}').right == 2


def test_pose_has_wrapped_yaw_and_unit_quaternion() -> None:
    pose = make_pose(1.0, 1, 2, 3 * math.pi / 2, v=0.1, w=-0.2)
    assert pose.yaw == pytest.approx(-math.pi / 2)
    q = pose.orientation
    assert q.x == q.y == 0.0
    assert q.z**2 + q.w**2 == pytest.approx(1.0)
    assert 2 * math.atan2(q.z, q.w) == pytest.approx(pose.yaw)
    data = json.loads(encode(pose))
    assert set(data) == {"stamp", "x", "y", "yaw", "v", "w", "orientation"}
    assert decode(Pose, encode(pose)) == pose
    with pytest.raises(msgspec.ValidationError):
        msgspec.convert({**data, "x": float("nan")}, Pose)


@given(st.floats(min_value=-1e6, max_value=1e6, allow_nan=False))
def test_wrap_angle_stays_in_range_and_keeps_the_direction(angle: float) -> None:
    wrapped = wrap_angle(angle)
    assert -math.pi <= wrapped <= math.pi
    assert math.cos(wrapped) == pytest.approx(math.cos(angle), abs=1e-6)
    assert math.sin(wrapped) == pytest.approx(math.sin(angle), abs=1e-6)


@given(st.binary(max_size=300))
def test_decode_never_raises_anything_but_payload_error(payload: bytes) -> None:
    for message_type in MESSAGE_TYPES.values():
        try:
            decode(message_type, payload)
        except PayloadError:
            pass


def test_excerpt_is_short_and_printable() -> None:
    text = excerpt(b"\x00\x01" + "é".encode() + b"x" * 500)
    assert len(text) <= 80 and text.isprintable() and text.endswith("...")
    assert excerpt(b'{"a":1}') == '{"a":1}'


def test_payload_bytes_reads_a_sample_and_never_raises() -> None:
    class ZBytes:
        def __init__(self, data: object) -> None:
            self.data = data

        def to_bytes(self) -> object:
            if isinstance(self.data, Exception):
                raise self.data
            return self.data

    class Sample:
        def __init__(self, data: object) -> None:
            self.payload = ZBytes(data)

    assert payload_bytes(Sample(b'{"a":1}')) == b'{"a":1}'
    assert payload_bytes(Sample(bytearray(b"xy"))) == b"xy" and type(payload_bytes(Sample(bytearray(b"xy")))) is bytes
    assert payload_bytes(Sample(RuntimeError("freed"))) == b""  # what Zenoh cannot give is empty, on Zenoh's thread
    assert payload_bytes(object()) == b""


def test_json_schema_for_every_message_validates_its_examples() -> None:
    schemas = json_schemas()
    assert set(schemas) == set(MESSAGE_TYPES)
    twist = schemas["Twist"]
    assert twist["$defs"]["Twist"]["additionalProperties"] is False
    assert twist["$defs"]["Twist"]["required"] == []
    error = schemas["ErrorReport"]["$defs"]["ErrorReport"]
    assert {"stamp", "source", "key", "reason"} <= set(error["required"])
    json.dumps(schemas)  # serialisable


def test_error_report_encodes_as_json() -> None:
    report = ErrorReport(stamp=1.0, source="gateway", key="robot/cmd_vel", reason="bad", excerpt="x")
    assert json.loads(encode(report))["reason"] == "bad"


@pytest.mark.parametrize(
    ("kind", "fields", "bad"),
    [
        (WheelImpulses, {"seq": 1, "stamp": 1.0, "left": 1, "right": 1, "mono": 2.0}, ["stamp", "mono"]),
        (Pose, {"stamp": 1.0, "x": 0.0, "y": 0.0, "yaw": 0.0, "v": 0.0, "w": 0.0}, ["stamp", "x", "y", "yaw", "v", "w"]),
    ],
)
def test_every_float_of_impulses_and_poses_must_be_finite_and_is_named(kind: type, fields: dict[str, Any], bad: list[str]) -> None:
    kind(**fields)
    for name in bad:
        for value in (math.nan, math.inf, -math.inf):
            with pytest.raises(ValueError, match=rf"\.{name} must be a finite number"):
                kind(**{**fields, name: value})
            with pytest.raises(PayloadError):
                decode(kind, msgspec.json.encode({**fields, name: value}).replace(b"null", b"1e999"))
