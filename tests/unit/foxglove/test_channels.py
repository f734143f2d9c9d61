"""The view's channel plumbing: JSON Schemas, Foxglove's message builders, and the channels made on the SDK's context."""

from __future__ import annotations

import json

from blackmetal.foxglove.channels import HEADER, Kind, array, foxglove_channel, message_schema, obj, report_log, timestamp, transform, typed
from blackmetal.schemas import ErrorReport


def test_schemas_are_titled_with_the_message_type_panels_look_for() -> None:
    schema = message_schema("WheelSpeeds", "speeds", {"left": typed("number")}, ["left"])
    assert schema == {
        "title": "WheelSpeeds",
        "description": "speeds",
        "type": "object",
        "properties": {"left": {"type": "number"}},
        "required": ["left"],
    }
    assert "required" not in message_schema("T", "d", {})
    assert array(typed("string"), description="ids") == {"type": "array", "items": {"type": "string"}, "description": "ids"}
    assert obj(a=typed(["number", "null"])) == {"type": "object", "properties": {"a": {"type": ["number", "null"]}}}
    assert HEADER["properties"]["frame_id"] == {"type": "string"}


def test_the_builders_carry_the_stamp_frames_and_the_report() -> None:
    stamp = timestamp(12.5)
    assert (stamp.sec, stamp.nsec) == (12, 500_000_000)
    assert b"r1/odom" in transform(1.0, "r1/odom", "r1/base_link", (1.0, 2.0, 0.0), (0.0, 0.0, 0.0, 1.0)).encode()
    log = report_log(ErrorReport(stamp=3.0, source="gateway", key="robot/cmd_vel", reason="too fast")).encode()
    assert b"robot/cmd_vel: too fast" in log and b"gateway" in log


def test_a_channel_of_each_kind_is_made_on_the_sdks_context() -> None:
    schema = message_schema("Pose", "a pose", {"x": typed("number")})
    channels = {kind: foxglove_channel(f"/t/{kind.name}", kind, schema if kind is Kind.JSON else None) for kind in Kind}
    try:
        assert all(not channel.has_sinks() for channel in channels.values()), "nobody subscribed"
        channels[Kind.JSON].log(json.dumps({"x": 1.0}).encode())  # nobody takes it: a no-op
    finally:
        for channel in channels.values():
            getattr(channel, "close", lambda: None)()
