"""The key space: every key expression blackmetal uses, with the message carried on it.

One robot lives under one prefix (``robot`` by default, ``fleet/a`` in a fleet). Services, tools, tests and the JSON
Schema export take their keys from :class:`Keys` and nowhere else, so a key is renamed in one place.
"""

from __future__ import annotations

from enum import StrEnum
from typing import NamedTuple

import msgspec

from .errors import ConfigError
from .messages import (
    ROBOT_MESSAGE_TYPES,
    DriverChange,
    ErrorReport,
    EStop,
    GatewayHealth,
    GatewayParams,
    Lock,
    ParamsSet,
    ParamsSetReply,
    Pose,
    PoseReset,
    RobotStatus,
    SimFaults,
    Twist,
    WheelImpulses,
)
from .navigation import (
    NAV_MESSAGE_TYPES,
    MapPose,
    NavCancel,
    NavCancelReply,
    NavFeedback,
    NavGoal,
    NavGoalReply,
    NavMove,
    NavResult,
    NavResultQuery,
    SetPose,
)
from .wheels import WHEEL_MESSAGE_TYPES, WheelMove, WheelMoveReply, WheelPosition

DEFAULT_PREFIX = "robot"

#: Every message type, by the name used for its JSON Schema file.
MESSAGE_TYPES: dict[str, type[msgspec.Struct]] = {**ROBOT_MESSAGE_TYPES, **NAV_MESSAGE_TYPES, **WHEEL_MESSAGE_TYPES}


class Delivery(StrEnum):
    """How a publication travels when a link or a consumer cannot keep up (Zenoh's congestion control).

    ``telemetry`` is dropped for the congested link alone: a pose, a health report or a wheel sample is replaced by the
    next one, and a router never holds one host's telemetry (or commands) behind another's dead link. A ``command`` is
    never dropped: it waits for room, as a stop must reach the robot; commands are few and small.
    """

    TELEMETRY = "telemetry"
    COMMAND = "command"


class KeySpec(NamedTuple):
    """One key below the prefix: the attribute that names it, what travels on it, how it is delivered (who uses it: the
    README's key table).

    A chunk in angle brackets (``cmd_vel/<source>``) stands for any one name: :meth:`Keys.cmd_vel_of` and
    :meth:`Keys.lock_of` fill it in.
    """

    name: str
    suffix: str
    message: type[msgspec.Struct] | None
    kind: str  # "publication", "query" or "liveliness"
    delivery: Delivery | None = None  # publications only
    reply: type[msgspec.Struct] | None = None  # queries only: what the answer carries


#: Every key, in the order the README's table lists them.
KEY_SPECS: tuple[KeySpec, ...] = (
    KeySpec("cmd_vel", "cmd_vel", Twist, "publication", Delivery.COMMAND),
    KeySpec("cmd_vel_source", "cmd_vel/<source>", Twist, "publication", Delivery.COMMAND),
    KeySpec("lock", "lock/<name>", Lock, "publication", Delivery.COMMAND),
    KeySpec("estop", "estop", EStop, "publication", Delivery.COMMAND),
    KeySpec("estop_release", "estop/release", EStop, "publication", Delivery.COMMAND),
    KeySpec("impulses", "wheels/impulses", WheelImpulses, "publication", Delivery.TELEMETRY),
    KeySpec("wheels_move", "wheels/move", WheelMove, "query", reply=WheelMoveReply),
    KeySpec("wheels_position", "wheels/position", WheelPosition, "publication", Delivery.TELEMETRY),
    KeySpec("status", "status", RobotStatus, "publication", Delivery.TELEMETRY),
    KeySpec("health", "gateway/health", GatewayHealth, "publication", Delivery.TELEMETRY),
    KeySpec("driver", "gateway/driver", DriverChange, "publication", Delivery.TELEMETRY),
    KeySpec("params", "gateway/params", GatewayParams, "publication", Delivery.TELEMETRY),
    KeySpec("params_set", "gateway/params/set", ParamsSet, "query", reply=ParamsSetReply),
    KeySpec("errors", "errors", ErrorReport, "publication", Delivery.TELEMETRY),
    KeySpec("pose", "pose", Pose, "publication", Delivery.TELEMETRY),
    KeySpec("odometry_reset", "odometry/reset", PoseReset, "query", reply=Pose),
    KeySpec("nav_goal", "nav/goal", NavGoal, "query", reply=NavGoalReply),
    KeySpec("nav_move", "nav/move", NavMove, "query", reply=NavGoalReply),
    KeySpec("nav_cancel", "nav/cancel", NavCancel, "query", reply=NavCancelReply),
    KeySpec("nav_feedback", "nav/feedback", NavFeedback, "publication", Delivery.TELEMETRY),
    KeySpec("nav_result", "nav/result", NavResultQuery, "query", reply=NavResult),
    KeySpec("nav_map_pose", "nav/map_pose", MapPose, "publication", Delivery.TELEMETRY),
    KeySpec("nav_set_pose", "nav/set_pose", SetPose, "query", reply=MapPose),
    KeySpec("nav_params", "nav/params", GatewayParams, "publication", Delivery.TELEMETRY),
    KeySpec("nav_params_set", "nav/params/set", ParamsSet, "query", reply=ParamsSetReply),
    KeySpec("alive_gateway", "alive/gateway", None, "liveliness"),
    KeySpec("alive_odometry", "alive/odometry", None, "liveliness"),
    KeySpec("alive_sim", "alive/sim", None, "liveliness"),
    KeySpec("alive_nav", "alive/nav", None, "liveliness"),
    KeySpec("sim_truth", "sim/truth", Pose, "publication", Delivery.TELEMETRY),
    KeySpec("sim_faults", "sim/faults", SimFaults, "publication", Delivery.COMMAND),
)


def _spec_of(key: str, prefix: str) -> KeySpec | None:
    """The row of ``key``, matched on its chunks after ``prefix`` (a prefix may itself end in ``cmd_vel``)."""
    if not key.startswith(prefix + "/"):
        return None
    chunks = key[len(prefix) + 1 :].split("/")
    for spec in KEY_SPECS:
        pattern = spec.suffix.split("/")
        if len(pattern) == len(chunks) and all(p == c or p.startswith("<") for p, c in zip(pattern, chunks, strict=True)):
            return spec
    return None


def delivery_of(key: str, prefix: str) -> Delivery:
    """How the publication on ``key`` under ``prefix`` travels: the key space decides, no publisher chooses.

    ValueError for a key that is not one of blackmetal's publications."""
    spec = _spec_of(key, prefix)
    if spec is None or spec.delivery is None:
        raise ValueError(f"{key!r} is not a blackmetal publication key (see schemas/keys.py KEY_SPECS)")
    return spec.delivery


class Sources:
    """The command sources blackmetal's own commanders publish as (``<prefix>/cmd_vel/<source>``); the gateway's defaults."""

    DEFAULT = "default"  # plain <prefix>/cmd_vel
    TELEOP = "teleop"
    FOXGLOVE = "foxglove"
    ROS2 = "ros2"
    NAV = "nav"


def any_alive(role: str) -> str:
    """The liveliness key expression that matches ``role``'s token (``gateway``, ``odometry``, ``sim``) under every prefix."""
    return f"**/alive/{role}"


#: Liveliness key expression that matches every robot's gateway, whatever its prefix.
ANY_GATEWAY_ALIVE = any_alive("gateway")


def validate_prefix(prefix: str) -> str:
    """A key-expression prefix such as ``robot`` or ``fleet/a``: no wildcards, no empty chunks."""
    chunks = prefix.split("/")
    if not prefix or any(not chunk for chunk in chunks):
        raise ConfigError(f"prefix {prefix!r} must be non-empty chunks separated by '/', e.g. 'robot' or 'fleet/a'")
    for chunk in chunks:
        if any(ch in chunk for ch in "*$?#") or chunk.startswith("@"):
            raise ConfigError(f"prefix {prefix!r} must not contain wildcards or the characters * $ ? # or a leading @")
        if chunk in (".", ".."):
            raise ConfigError(f"prefix {prefix!r} must not have a '.' or '..' part: a key expression is not a path")
        if not chunk.isprintable() or any(ch.isspace() for ch in chunk):
            raise ConfigError(f"prefix {prefix!r} must be printable characters without spaces or control characters")
    return prefix


class Keys:
    """The key expressions of the robot under ``prefix``; ``Keys("fleet/a").pose == "fleet/a/pose"``."""

    cmd_vel: str
    cmd_vel_source: str
    lock: str
    estop: str
    estop_release: str
    impulses: str
    wheels_move: str
    wheels_position: str
    status: str
    health: str
    driver: str
    params: str
    params_set: str
    errors: str
    pose: str
    odometry_reset: str
    nav_goal: str
    nav_move: str
    nav_cancel: str
    nav_feedback: str
    nav_result: str
    nav_map_pose: str
    nav_set_pose: str
    nav_params: str
    nav_params_set: str
    alive_gateway: str
    alive_odometry: str
    alive_sim: str
    alive_nav: str
    sim_truth: str
    sim_faults: str

    def __init__(self, prefix: str = DEFAULT_PREFIX) -> None:
        self.prefix = validate_prefix(prefix)
        for spec in KEY_SPECS:
            setattr(self, spec.name, f"{prefix}/{spec.suffix}")

    def cmd_vel_of(self, source: str) -> str:
        """The key of the command source ``source`` (``default`` is plain ``cmd_vel``)."""
        return self.cmd_vel if source == Sources.DEFAULT else f"{self.prefix}/cmd_vel/{source}"

    def estop_for(self, engage: bool) -> str:
        """Where an engage goes (``estop``, any user) and where a release goes (``estop/release``, a safety role)."""
        return self.estop if engage else self.estop_release

    def alive(self, role: str) -> str:
        """The liveliness token of ``role`` (``gateway``, ``odometry``, ``sim``) under this prefix."""
        return f"{self.prefix}/alive/{role}"

    def lock_of(self, name: str) -> str:
        return f"{self.prefix}/lock/{name}"

    @property
    def any_cmd_vel_source(self) -> str:
        """Every named command source's key (not plain ``cmd_vel``)."""
        return f"{self.prefix}/cmd_vel/*"

    @property
    def any_lock(self) -> str:
        return f"{self.prefix}/lock/*"

    @property
    def everything(self) -> str:
        """Every key of this robot (for recorders and viewers)."""
        return f"{self.prefix}/**"

    def message_for(self, key: str) -> type[msgspec.Struct] | None:
        """The message type carried on ``key`` (None for liveliness keys and keys not ours)."""
        spec = _spec_of(key, self.prefix)
        return None if spec is None else spec.message

    @staticmethod
    def prefix_of_gateway_token(key: str) -> str:
        """``fleet/a`` from the liveliness key ``fleet/a/alive/gateway``."""
        return Keys.prefix_of_token(key, "gateway")

    @staticmethod
    def prefix_of_token(key: str, role: str) -> str:
        """``fleet/a`` from the liveliness key ``fleet/a/alive/<role>``."""
        return key.removesuffix(f"/alive/{role}")

    def __repr__(self) -> str:
        return f"Keys({self.prefix!r})"
