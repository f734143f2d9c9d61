"""The view's channel plumbing: what a channel carries (:class:`Kind`), how one is made, and Foxglove's message builders.

Apart so that the live and fleet views log into the same kinds of channel, and tests count messages with a
channel factory of their own (:data:`ChannelFactory`) instead of the SDK's.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from enum import Enum
from typing import Any, Protocol, cast

from blackmetal.schemas import ErrorReport, Pose, stamp_parts


def typed(name: str | list[str], **more: Any) -> dict[str, Any]:
    return {"type": name, **more}


def array(items: dict[str, Any], **more: Any) -> dict[str, Any]:
    return {"type": "array", "items": items, **more}


def obj(**properties: Any) -> dict[str, Any]:
    return {"type": "object", "properties": properties}


#: ROS's std_msgs/msg/Header as JSON.
HEADER = obj(stamp=obj(sec=typed("integer"), nsec=typed("integer")), frame_id=typed("string"))


def message_schema(title: str, description: str, properties: dict[str, Any], required: list[str] | None = None) -> dict[str, Any]:
    """The JSON Schema of a JSON channel's messages, titled with the message type's name (what the panels look for)."""
    schema = {"title": title, "description": description, **obj(**properties)}
    return schema if required is None else {**schema, "required": required}


_ENUM_TYPES = {str: "string", bool: "boolean", int: "integer", float: "number"}


def studio_schema(schema: dict[str, Any]) -> dict[str, Any]:
    """The schema as Foxglove Studio's (and Lichtblick's) JSON Schema parser takes it: ``"type": "object"`` at the top,
    every field one plain type (#40: a top-level ``$ref`` / ``$defs`` had the app refuse /odometry, /status, /health).

    References are inlined, ``X | None`` is ``X``, a tuple is an array of its first item's type, an enum is its values'
    type, a dict an object with no fixed properties. The messages themselves are unchanged.
    """
    defs = schema.get("$defs", {})

    def plain(node: Any, seen: frozenset[str]) -> Any:
        if isinstance(node, list):
            return [plain(item, seen) for item in node]
        if not isinstance(node, dict):
            return node
        node = {key: value for key, value in node.items() if key != "$defs"}
        ref = node.pop("$ref", None)
        if isinstance(ref, str) and ref.startswith("#/$defs/"):
            name = ref.removeprefix("#/$defs/")
            target = {"type": "object", "properties": {}} if name in seen else plain(defs.get(name, {}), seen | {name})
            node = {**target, **node}
        for union in ("anyOf", "oneOf"):
            choices = node.get(union)
            if isinstance(choices, list) and not all(isinstance(c, dict) and isinstance(c.get("const"), int) for c in choices):
                del node[union]
                real = [c for c in choices if not (isinstance(c, dict) and c.get("type") == "null")] or [{"type": "string"}]
                node = {**plain(real[0], seen), **node}
        kind = node.get("type")
        if isinstance(kind, list):
            node["type"] = next((k for k in kind if k != "null"), "string")
        elif kind is None and isinstance(node.get("enum"), list) and node["enum"]:
            node["type"] = _ENUM_TYPES.get(type(node["enum"][0]), "string")
        elif kind is None and "properties" in node:
            node["type"] = "object"
        if node.get("type") == "object":
            node["properties"] = {name: plain(field, seen) for name, field in node.get("properties", {}).items()}
            node.pop("additionalProperties", None)
        elif node.get("type") == "array":
            items, prefix = node.get("items"), node.pop("prefixItems", None)
            if not isinstance(items, dict):
                items = prefix[0] if isinstance(prefix, list) and prefix else {"type": "number"}
            node["items"] = plain(items, seen)
        return node

    return dict(plain(schema, frozenset()))


def timestamp(stamp: float) -> Any:
    from foxglove.messages import Timestamp

    sec, nsec = stamp_parts(stamp)
    return Timestamp(sec=sec, nsec=nsec)


def fox_pose(pose: Pose) -> Any:
    from foxglove.messages import Pose as FoxPose
    from foxglove.messages import Quaternion, Vector3

    q = pose.orientation
    return FoxPose(position=Vector3(x=pose.x, y=pose.y, z=0.0), orientation=Quaternion(x=q.x, y=q.y, z=q.z, w=q.w))


class Kind(Enum):
    """What a view channel carries: one of Foxglove's own types (protobuf, built by the SDK), or JSON with a schema."""

    POSE = "foxglove.PoseInFrame"
    POSES = "foxglove.PosesInFrame"
    TRANSFORM = "foxglove.FrameTransform"
    LOG = "foxglove.Log"
    JSON = "json"


class Out(Protocol):
    """A channel as the view uses it: does anyone take it (a client's subscription, the MCAP file), and log a message."""

    def has_sinks(self) -> bool: ...
    def log(self, msg: Any) -> None: ...


#: Makes the view's channels: ``(topic, kind, JSON schema or None) -> channel``. Tests give one that counts.
ChannelFactory = Callable[[str, Kind, "dict[str, Any] | None"], Out]


def foxglove_channel(topic: str, kind: Kind, schema: dict[str, Any] | None = None) -> Out:
    from foxglove.channels import FrameTransformChannel, LogChannel, PoseInFrameChannel, PosesInFrameChannel

    typed: dict[Kind, Callable[[str], Any]] = {
        Kind.POSE: PoseInFrameChannel,
        Kind.POSES: PosesInFrameChannel,
        Kind.TRANSFORM: FrameTransformChannel,
        Kind.LOG: LogChannel,
    }
    if kind is Kind.JSON:
        import foxglove

        assert schema is not None
        full = foxglove.Schema(name=schema["title"], encoding="jsonschema", data=json.dumps(studio_schema(schema)).encode())
        return cast(Out, foxglove.Channel(topic, schema=full, message_encoding="json"))
    return cast(Out, typed[kind](topic))


def transform(stamp: float, parent: str, child: str, xyz: tuple[float, float, float], q: tuple[float, float, float, float]) -> Any:
    from foxglove.messages import FrameTransform, Quaternion, Vector3

    return FrameTransform(
        timestamp=timestamp(stamp),
        parent_frame_id=parent,
        child_frame_id=child,
        translation=Vector3(x=xyz[0], y=xyz[1], z=xyz[2]),
        rotation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]),
    )


def report_log(report: ErrorReport) -> Any:
    """An error report as one line of Foxglove's Log panel (a warning, named by who reported it)."""
    from foxglove.messages import Log, LogLevel

    return Log(timestamp=timestamp(report.stamp), level=LogLevel.Warning, message=f"{report.key}: {report.reason}", name=report.source)
