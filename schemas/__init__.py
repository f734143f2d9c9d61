"""Wire messages of the Black Metal gateway: msgspec Structs, JSON by default, no I/O."""

from .codec import MAX_PAYLOAD_BYTES, decode, encode, excerpt, to_bytes
from .errors import PayloadError, SchemaError
from .jsonschema import json_schemas
from .messages import (
    DIRECTION_NAMES,
    MESSAGE_TYPES,
    STATE_NAMES,
    EStop,
    ErrorReport,
    GatewayHealth,
    LinkHealth,
    Pose,
    PoseReset,
    Quaternion,
    RobotStatus,
    SimFaults,
    Twist,
    Vector3,
    WheelImpulses,
    make_pose,
    wrap_angle,
    yaw_quaternion,
)

__all__ = [
    "DIRECTION_NAMES",
    "MAX_PAYLOAD_BYTES",
    "MESSAGE_TYPES",
    "STATE_NAMES",
    "EStop",
    "ErrorReport",
    "GatewayHealth",
    "LinkHealth",
    "PayloadError",
    "Pose",
    "PoseReset",
    "Quaternion",
    "RobotStatus",
    "SchemaError",
    "SimFaults",
    "Twist",
    "Vector3",
    "WheelImpulses",
    "decode",
    "encode",
    "excerpt",
    "json_schemas",
    "make_pose",
    "to_bytes",
    "wrap_angle",
    "yaw_quaternion",
]
