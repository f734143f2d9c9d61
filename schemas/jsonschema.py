"""JSON Schemas of every message, so clients in other languages can validate."""

from __future__ import annotations

from typing import Any

import msgspec

from .messages import MESSAGE_TYPES

#: Which key expression (below the prefix) carries each message.
MESSAGE_KEYS: dict[str, str] = {
    "Twist": "cmd_vel",
    "EStop": "estop",
    "WheelImpulses": "wheels/impulses",
    "Pose": "pose, sim/truth",
    "RobotStatus": "status",
    "GatewayHealth": "gateway/health",
    "ErrorReport": "errors",
    "SimFaults": "sim/faults",
    "PoseReset": "odometry/reset (query payload)",
}


def json_schemas() -> dict[str, dict[str, Any]]:
    """One self-contained JSON Schema (draft 2020-12) per message type."""
    schemas: dict[str, dict[str, Any]] = {}
    for name, message_type in MESSAGE_TYPES.items():
        schema = msgspec.json.schema(message_type)
        schema = {
            "$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": name,
            "description": f"blackmetal message on <prefix>/{MESSAGE_KEYS[name]}",
            **schema,
        }
        schemas[name] = schema
    return schemas
