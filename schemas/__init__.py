"""Wire messages of the Black Metal gateway: msgspec Structs, JSON by default, no I/O."""

from .codec import MAX_PAYLOAD_BYTES, decode, encode, excerpt, payload_bytes, to_bytes  # noqa: F401
from .errors import BlackmetalError, ConfigError, MissingExtra, PayloadError, ZenohUnavailable, ZenohUnreachable, require_extra  # noqa: F401
from .jsonschema import json_schemas  # noqa: F401
from .keys import (  # noqa: F401
    ANY_GATEWAY_ALIVE,
    DEFAULT_PREFIX,
    KEY_SPECS,
    MESSAGE_TYPES,
    Delivery,
    Keys,
    KeySpec,
    Sources,
    any_alive,
    delivery_of,
    validate_prefix,
)
from .messages import (  # noqa: F401
    DIRECTION_NAMES,
    STATE_NAMES,
    DriverChange,
    ErrorReport,
    EStop,
    GatewayHealth,
    GatewayParams,
    LinkHealth,
    Lock,
    Param,
    ParamResult,
    ParamsSet,
    ParamsSetReply,
    ParamValue,
    Pose,
    PoseReset,
    Quaternion,
    RobotStatus,
    SimFaults,
    SourceHealth,
    Twist,
    Vector3,
    WheelImpulses,
    make_pose,
    stamp_parts,
    wrap_angle,
    yaw_quaternion,
)
from .navigation import (  # noqa: F401
    GoalState,
    MapPose,
    NavCancel,
    NavCancelReply,
    NavFeedback,
    NavGoal,
    NavGoalReply,
    NavMove,
    NavResult,
    NavResultQuery,
    PlanarPose,
    SetPose,
)
from .wheels import MoveState, WheelMove, WheelMoveReply, WheelPosition  # noqa: F401
