"""msgspec Structs for every message on the wire (JSON by default).

No I/O here: the services and any client import these to encode and decode.
Inputs that come from arbitrary clients (``Twist``, ``EStop``) forbid unknown
fields so that a typo such as ``{"linear": {"X": 0.2}}`` is an error rather
than a silent zero; messages between our own services tolerate extra fields so
that a newer publisher does not break an older subscriber.
"""

from __future__ import annotations

import math
import time
from typing import Annotated

import msgspec

Finite = Annotated[float, msgspec.Meta(description="a finite number (no NaN or infinity)")]


def _require_finite(owner: str, **values: float) -> None:
    """Called when the sum of ``values`` is not finite (the quick test every message passes): names the culprit, if any."""
    for name, value in values.items():
        if not math.isfinite(value):
            raise ValueError(f"{owner}.{name} must be a finite number, got {value!r}")


class Vector3(msgspec.Struct, forbid_unknown_fields=True):
    """A 3-vector; every component optional, default 0."""

    x: Finite = 0.0
    y: Finite = 0.0
    z: Finite = 0.0

    def __post_init__(self) -> None:
        if not math.isfinite(self.x + self.y + self.z):
            _require_finite("vector", x=self.x, y=self.y, z=self.z)


class Twist(msgspec.Struct, forbid_unknown_fields=True):
    """Velocity command in the ROS ``geometry_msgs/Twist`` shape.

    ``linear.x`` is forward speed in m/s, ``angular.z`` the turn rate in rad/s
    (positive turns left, REP-103). Missing fields are 0, so
    ``{"linear":{"x":0.2}}`` is a complete command.
    """

    linear: Vector3 = msgspec.field(default_factory=Vector3)
    angular: Vector3 = msgspec.field(default_factory=Vector3)


class EStop(msgspec.Struct, forbid_unknown_fields=True):
    """Emergency stop: ``{"engaged": true}`` latches, ``{"engaged": false}`` releases."""

    engaged: bool


class Lock(msgspec.Struct, forbid_unknown_fields=True):
    """A lock on ``<prefix>/lock/<name>``: ``{"locked": true}`` blocks the command sources of its priority and below."""

    locked: bool


class WheelImpulses(msgspec.Struct):
    """One wheel-speed reading, exactly as the robot reported it.

    ``left``/``right`` are encoder impulses per second; the right encoder is
    mirrored (negative when the wheel drives forward). ``stamp`` is the Unix
    time in seconds at which the reply arrived at the gateway; ``seq`` counts
    readings from 0 and starts over when the gateway restarts. ``mono`` is
    the same instant on the gateway's monotonic clock (seconds, arbitrary
    origin): the odometry integrates over its differences, which no clock
    step can bend. ``source`` names the gateway run that published the
    sample; it changes when the gateway restarts. Both are optional only so
    that older recordings still replay: the live odometry rejects (and
    reports) a sample without them.
    """

    seq: Annotated[int, msgspec.Meta(ge=0)]
    stamp: Finite
    left: int
    right: int
    mono: Finite | None = None
    source: Annotated[str, msgspec.Meta(max_length=64)] | None = None

    def __post_init__(self) -> None:
        mono = self.mono
        if not math.isfinite(self.stamp if mono is None else self.stamp + mono):
            _require_finite("impulses", stamp=self.stamp, **({} if mono is None else {"mono": mono}))


class Quaternion(msgspec.Struct):
    """Unit quaternion (x, y, z, w)."""

    x: Finite = 0.0
    y: Finite = 0.0
    z: Finite = 0.0
    w: Finite = 1.0


class Pose(msgspec.Struct):
    """A planar pose with its velocity, for odometry and the simulator's truth.

    ``x``/``y`` in metres, ``yaw`` in radians wrapped to [-pi, pi], ``v`` the
    forward speed (m/s), ``w`` the turn rate (rad/s), ``orientation`` the unit
    quaternion of ``yaw`` for clients that want ROS-style orientation.
    """

    stamp: Finite
    x: Finite
    y: Finite
    yaw: Finite
    v: Finite = 0.0
    w: Finite = 0.0
    orientation: Quaternion = msgspec.field(default_factory=Quaternion)

    def __post_init__(self) -> None:
        if not math.isfinite(self.stamp + self.x + self.y + self.yaw + self.v + self.w):
            _require_finite("pose", stamp=self.stamp, x=self.x, y=self.y, yaw=self.yaw, v=self.v, w=self.w)


def wrap_angle(angle: float) -> float:
    return math.remainder(angle, math.tau)


def yaw_quaternion(yaw: float) -> Quaternion:
    """The unit quaternion of a rotation by ``yaw`` about z."""
    half = 0.5 * yaw
    return Quaternion(x=0.0, y=0.0, z=math.sin(half), w=math.cos(half))


def stamp_parts(stamp: float) -> tuple[int, int]:
    """Unix seconds -> (sec, nanosec), as ROS and Foxglove timestamps hold them (whole seconds first: no 1e18 rounding)."""
    sec = math.floor(stamp)
    nanosec = round((stamp - sec) * 1e9)
    if nanosec >= 1_000_000_000:
        sec, nanosec = sec + 1, nanosec - 1_000_000_000
    return int(sec), int(nanosec)


def make_pose(stamp: float, x: float, y: float, yaw: float, v: float = 0.0, w: float = 0.0) -> Pose:
    """Build a :class:`Pose` with the yaw wrapped and its quaternion filled in."""
    yaw = wrap_angle(float(yaw))
    return Pose(stamp=float(stamp), x=float(x), y=float(y), yaw=yaw, v=float(v), w=float(w), orientation=yaw_quaternion(yaw))


STATE_NAMES: dict[int, str] = {0: "UNKNOWN", 1: "READY", 2: "ERROR", 3: "RUN", 4: "SHUTDOWN"}
DIRECTION_NAMES: dict[int, str] = {1: "NORTH", 2: "SOUTH", 3: "WEST", 4: "EAST"}


class RobotStatus(msgspec.Struct):
    """The robot's state report from its log port, with readable names."""

    stamp: Finite
    state: int
    state_name: str
    direction: int
    direction_name: str

    @classmethod
    def from_codes(cls, stamp: float, state: int, direction: int) -> "RobotStatus":
        return cls(
            stamp=stamp,
            state=state,
            state_name=STATE_NAMES.get(state, f"UNKNOWN({state})"),
            direction=direction,
            direction_name=DIRECTION_NAMES.get(direction, f"UNKNOWN({direction})"),
        )


class LinkHealth(msgspec.Struct):
    """State of one TCP link to the robot."""

    state: str  # "connected", "connecting" or "down"
    connected_since: float | None = None
    reconnects: int = 0
    #: Why the link is not connected (the last failure: "cannot connect to 192.0.2.1:665: Connection refused"); None while up.
    reason: str | None = None


class SourceHealth(msgspec.Struct):
    """One command source in the gateway's health: ``age`` is None until it has sent a command."""

    priority: int
    age: float | None = None
    #: Commands the arbiter did not follow because another source drove or a lock blocked this one.
    dropped: int = 0
    #: Commands superseded by a newer one of the same source before the gateway took them (it publishes too fast).
    superseded: int = 0


class GatewayHealth(msgspec.Struct):
    """The gateway's periodic self-report: links, counters, safety state."""

    stamp: Finite
    control: LinkHealth
    log: LinkHealth
    commands_sent: int = 0
    polls: int = 0
    replies: int = 0
    full_buffer: int = 0
    full_buffer_retries: int = 0
    malformed_replies: int = 0
    garbage_bytes: int = 0
    rejected_inputs: int = 0
    keepalives: int = 0
    #: Requests given up: no reply within the reply timeout, or the link went down first.
    lost_replies: int = 0
    #: Polls not sent: one already waited a whole period for the poll before it, or the robot was behind (polls never
    #: queue up; a poll due while the one before it is unanswered goes out as soon as that one's reading comes).
    polls_skipped: int = 0
    estop: bool = False
    #: When the e-stop took its present state (Unix time), and what put it there: the key of the engage or release,
    #: or why the gateway started engaged. Kept across restarts, as the latch itself.
    estop_since: float | None = None
    estop_by: str | None = None
    cmd_timeout_active: bool = False
    #: The command timeout (s; 0: none): a client that stalls has its last command run this long at most.
    cmd_timeout: float = 0.5
    last_rtt_ms: float | None = None
    poll_hz: float = 0.0
    wheel_speeds: tuple[float, float] = (0.0, 0.0)
    #: This gateway's run id (the ``source`` of its impulses): two different ones on a prefix are a conflict.
    source: str | None = None
    #: The run id of another gateway seen on this prefix (commands are refused until it leaves).
    conflict_with: str | None = None
    #: The command source that drives (None: nobody, or nobody since the last hand-over to nobody).
    active_source: str | None = None
    #: Every configured command source: its priority, seconds since its last command, commands dropped.
    sources: dict[str, SourceHealth] = {}
    #: Every configured lock: engaged or not.
    locks: dict[str, bool] = {}
    #: The last motion command written to the robot ("EMG_STOP", "NORMAL_STOP", "velocity 0.100 0.100": left, right
    #: m/s) and its Unix time: what the robot was sent, beside ``estop`` (what the gateway decided).
    last_sent: str | None = None
    last_sent_stamp: float | None = None

    def estop_text(self) -> str:
        """The e-stop in words, for views and diagnostics: ``ENGAGED since 2026-11-27 16:40:01 UTC by robot/estop``."""
        return ("ENGAGED" if self.estop else "released") + self.estop_origin()

    def estop_origin(self) -> str:
        """`` since 2026-11-27 16:40:01 UTC by robot/estop``: when the e-stop took its state and what put it there."""
        if self.estop_since is None:
            return ""
        return f" since {self.estop_since_text()} by {self.estop_by or 'unknown'}"

    def estop_since_text(self) -> str:
        """When the e-stop took its state, in UTC ("" if the gateway does not say)."""
        return "" if self.estop_since is None else time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(self.estop_since))


class DriverChange(msgspec.Struct):
    """Who drives the robot now, who drove before, and why: one message on every change of driver."""

    stamp: Finite
    source: str | None
    previous: str | None
    reason: str


class ErrorReport(msgspec.Struct):
    """One rejected input: where it came from, what was wrong, a short excerpt.

    ``suppressed`` counts reports of the same kind dropped by rate limiting
    since the previous report was published.
    """

    stamp: Finite
    source: str
    key: str
    reason: str
    excerpt: str = ""
    suppressed: int = 0


class PoseReset(msgspec.Struct, forbid_unknown_fields=True):
    """Payload of a ``get`` on ``<prefix>/odometry/reset``: the pose to reset to (default: zero)."""

    x: Finite = 0.0
    y: Finite = 0.0
    yaw: Finite = 0.0


Probability = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
Seconds = Annotated[float, msgspec.Meta(ge=0.0, le=60.0)]


class SimFaults(msgspec.Struct, forbid_unknown_fields=True):
    """Sensor and link faults the simulated robot injects on demand (all off by default).

    Probabilities are per reply (per wheel for ``dropout`` and ``spike``).
    Sent to ``<prefix>/sim/faults`` as a partial object to change only some.
    """

    dropout: Probability = 0.0
    spike: Probability = 0.0
    full_buffer: Probability = 0.0
    delay: Seconds = 0.0
    garbage: Probability = 0.0
    glue: Probability = 0.0
    split: Probability = 0.0
    disconnect: Probability = 0.0
    silent: bool = False


#: A parameter's value: JSON's bool, integer, number or string (ROS 2's bool, integer, double and string parameters).
ParamValue = bool | int | float | str


class Param(msgspec.Struct, omit_defaults=True):
    """One parameter of the gateway: its value and what may be done with it (ROS 2's ``ParameterDescriptor``, in JSON).

    ``type`` is ``bool``, ``integer``, ``double`` or ``string``; ``min`` and
    ``max`` bound a number; ``read_only`` ones describe the robot and the
    gateway's wiring and change only with a restart.
    """

    name: str
    type: str
    value: ParamValue
    description: str = ""
    read_only: bool = False
    min: float | None = None
    max: float | None = None


class GatewayParams(msgspec.Struct):
    """The gateway's parameters now (on ``<prefix>/gateway/params``: published when one changes, and answered to a get)."""

    stamp: Finite
    params: list[Param]
    #: The names this publication changed (empty in an answer to a get).
    changed: list[str] = []


class ParamsSet(msgspec.Struct, forbid_unknown_fields=True):
    """Payload of a get on ``<prefix>/gateway/params/set``: the values to set, by name, each on its own."""

    values: dict[str, ParamValue]


class ParamResult(msgspec.Struct):
    """What became of one value of a :class:`ParamsSet`: set, or refused with the reason (ROS 2's ``SetParametersResult``)."""

    name: str
    successful: bool
    reason: str = ""


class ParamsSetReply(msgspec.Struct):
    """The gateway's answer to a :class:`ParamsSet`: a result per value, in order, and the parameters after them."""

    results: list[ParamResult]
    params: GatewayParams


#: The robot's messages, by the name used for its JSON Schema file (every message: ``keys.MESSAGE_TYPES``).
ROBOT_MESSAGE_TYPES: dict[str, type[msgspec.Struct]] = {
    "Twist": Twist,
    "EStop": EStop,
    "Lock": Lock,
    "WheelImpulses": WheelImpulses,
    "Pose": Pose,
    "RobotStatus": RobotStatus,
    "GatewayHealth": GatewayHealth,
    "ErrorReport": ErrorReport,
    "DriverChange": DriverChange,
    "SimFaults": SimFaults,
    "PoseReset": PoseReset,
    "GatewayParams": GatewayParams,
    "ParamsSet": ParamsSet,
    "ParamsSetReply": ParamsSetReply,
}
