"""The view's channel plumbing: JSON Schemas, Foxglove's message builders, and the channels made on the SDK's context."""

from __future__ import annotations

import json
from typing import Any

from blackmetal.foxglove.channels import (
    HEADER,
    Kind,
    array,
    foxglove_channel,
    message_schema,
    obj,
    report_log,
    studio_schema,
    timestamp,
    transform,
    typed,
)
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


def studio_parses(schema: dict[str, Any], where: str = "") -> None:
    """Foxglove Studio's (and Lichtblick's) JSON Schema parser's rules (mcap-support's parseJsonSchema), as it applies
    them: an object at the top and at every nesting, every field one plain type, arrays of one plain type."""
    assert schema.get("type") == "object", f'{where or "top"}: expected "type": "object", got {schema.get("type")!r}'
    for name, field in schema["properties"].items():
        at = f"{where}.{name}"
        if isinstance(field.get("oneOf"), list):
            assert all(isinstance(choice.get("const"), int) for choice in field["oneOf"]), at
            continue
        kind = field.get("type")
        assert kind in ("boolean", "string", "number", "integer", "object", "array"), f"{at}: unsupported type {kind!r}"
        if kind == "string":
            assert field.get("contentEncoding") in (None, "base64"), at
        elif kind == "object":
            studio_parses(field, at)
        elif kind == "array":
            items = field["items"]
            assert items.get("type") in ("boolean", "string", "number", "integer", "object"), f"{at}[]: {items.get('type')!r}"
            if items["type"] == "object":
                studio_parses(items, f"{at}[]")


def test_every_json_channel_of_the_views_is_sent_in_the_shape_studio_parses() -> None:
    """#40: /odometry, /status, /health and /errors were refused for their top-level $ref; the nav feedback is new."""
    from blackmetal.foxglove.fleet_view import FleetView
    from blackmetal.schemas import Keys, json_schemas
    from unit.foxglove.test_fleet_view import Logged

    schemas: dict[str, dict[str, Any]] = {}

    def channel(topic: str, kind: Kind, schema: dict[str, Any] | None) -> Any:
        if schema is not None:
            schemas[topic] = schema
        return Logged(topic, kind, schema, {})

    FleetView([("r1", Keys("fleet/r1"), None, 10)], channel=channel)
    assert {"/r1/odometry", "/r1/status", "/r1/health", "/r1/errors", "/r1/nav/feedback", "/fleet/summary"} <= set(schemas)
    for topic, schema in {**schemas, **{name: s for name, s in json_schemas().items()}}.items():
        sent = studio_schema(schema)
        studio_parses(sent, topic)
        assert sent["title"] == schema["title"] and "$defs" not in json.dumps(sent) and "$ref" not in json.dumps(sent), topic
    feedback = studio_schema(json_schemas()["NavFeedback"])
    assert feedback["properties"]["state"]["type"] == "string" and feedback["properties"]["goal"]["properties"]["yaw"]["type"] == "number"
    assert studio_schema({"title": "T", "type": "object", "properties": {"a": {"type": ["number", "null"]}}})["properties"]["a"] == {
        "type": "number"
    }
