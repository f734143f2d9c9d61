"""The Foxglove view's core: what it shows (:class:`LiveView`) and what its clients may do (:class:`Controls`).

What it shows, built from the robot's payloads: Foxglove's own types where a
panel needs them, JSON elsewhere.

| Foxglove topic | schema | from |
|---|---|---|
| ``/pose`` | ``foxglove.PoseInFrame`` in ``odom`` | ``<prefix>/pose`` |
| ``/tf`` | ``foxglove.FrameTransform`` odom -> base_link (the 3D panel follows it) | ``<prefix>/pose`` |
| ``/path`` | ``foxglove.PosesInFrame``, the last ``path_length`` poses, 5 Hz | ``<prefix>/pose`` |
| ``/truth/pose``, ``/truth/path`` | the same for the simulator's true pose | ``<prefix>/sim/truth`` |
| ``/odometry`` | blackmetal ``Pose`` (JSON, with v and w for plots) | ``<prefix>/pose`` |
| ``/wheels`` | wheel speeds in m/s and impulses/s (JSON) | ``<prefix>/wheels/impulses`` |
| ``/status``, ``/health``, ``/errors`` | blackmetal JSON messages, as published | their keys |
| ``/diagnostics`` | ``diagnostic_msgs/msg/DiagnosticArray`` (JSON) from the gateway's health | ``<prefix>/gateway/health`` |
| ``/log`` | ``foxglove.Log``, one per error report (the Log panel) | ``<prefix>/errors`` |

Payloads that do not decode are skipped; the view never crashes on what a
key carries. The view has no clock and no timers: the paths are throttled on
the messages' own stamps.

What clients may do (client publish and services, JSON only):

| from the client | schema | to the robot |
|---|---|---|
| topic ``/cmd_vel`` | ``geometry_msgs/msg/Twist`` (or ``geometry_msgs/Twist``) | ``<prefix>/cmd_vel/foxglove``: the command source ``foxglove`` |
| topic ``/estop`` | ``std_msgs/msg/Bool``: ``{"data": true}`` engages, ``{"data": false}`` releases | ``<prefix>/estop`` |
| service ``set_estop`` | ``std_srvs/srv/SetBool`` | ``<prefix>/estop``; answers once the gateway's health confirms |
| service ``reset_odometry`` | ``blackmetal/srv/ResetOdometry`` (x, y, yaw; all optional) | a ``get`` on ``<prefix>/odometry/reset``; answers with the odometry's pose |

:class:`Controls` is pure and clock-injected like every core: each input
comes with ``now``; what is due later (a service call's time limit, the
re-sent engage of a ``set_estop``, summaries of rate-limited error reports)
runs in :meth:`Controls.tick` at :meth:`Controls.next_deadline`. A refused
client message is answered with a status message to that client and
reported on ``<prefix>/errors``; a failed service call is answered with a
service call failure and reported.

A fleet in one view (``--fleet``): :class:`FleetView` is one
:class:`LiveView` per robot with its topics under ``/<id>`` and its frames
``<id>/odom`` -> ``<id>/base_link`` on one ``/tf``, and ``/fleet/summary``
(:class:`FleetSummary`); :class:`FleetControls` is one :class:`Controls` per
robot (``/<id>/cmd_vel``, ``/<id>/estop``, services ``/<id>/set_estop``,
``/<id>/reset_odometry``), each fed only what names its robot. The names are
made in one place: :func:`robot_namespace`, :func:`robot_frame`,
:func:`control_topic`, :func:`service_name`, :func:`robot_of`.
"""

from __future__ import annotations

import json
import math
import time
from collections import deque
from collections.abc import Callable, Collection
from dataclasses import dataclass
from enum import Enum, IntEnum
from typing import Any, Protocol, cast

import msgspec

from blackmetal.robot_model import Encoders
from blackmetal.runtime.diagnostics import COMMANDS_REFUSED, ESTOP_ENGAGED, REPLIES_LOST_EVER, Level, Status, link_level
from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import (
    ErrorReport,
    EStop,
    GatewayHealth,
    GatewayParams,
    Keys,
    LinkHealth,
    PayloadError,
    Pose,
    PoseReset,
    RobotStatus,
    Sources,
    Twist,
    WheelImpulses,
    decode,
    encode,
    excerpt,
    json_schemas,
    stamp_parts,
)

from .model import JOINT_STATE_SCHEMA, STRING_SCHEMA, RobotModel, WheelAngles, joint_state, turned

#: How often the paths are sent (s of message time): a path is big, the pose is not.
PATH_PERIOD_S = 0.2

WHEELS_SCHEMA: dict[str, Any] = {
    "title": "WheelSpeeds",
    "description": "blackmetal wheel speeds, from <prefix>/wheels/impulses",
    "type": "object",
    "properties": {
        "stamp": {"type": "number"},
        "left_mps": {"type": "number"},
        "right_mps": {"type": "number"},
        "left_impulses": {"type": "integer"},
        "right_impulses": {"type": "integer"},
    },
    "required": ["stamp", "left_mps", "right_mps", "left_impulses", "right_impulses"],
}

_TIME_SCHEMA: dict[str, Any] = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}

#: ROS's diagnostic_msgs/msg/DiagnosticArray as JSON, the shape the Diagnostics panels read.
DIAGNOSTICS_SCHEMA: dict[str, Any] = {
    "title": "diagnostic_msgs/msg/DiagnosticArray",
    "description": "the gateway's health as ROS diagnostics, from <prefix>/gateway/health",
    "type": "object",
    "properties": {
        "header": {"type": "object", "properties": {"stamp": _TIME_SCHEMA, "frame_id": {"type": "string"}}},
        "status": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "level": {"type": "integer", "description": "0 OK, 1 WARN, 2 ERROR, 3 STALE"},
                    "name": {"type": "string"},
                    "message": {"type": "string"},
                    "hardware_id": {"type": "string"},
                    "values": {
                        "type": "array",
                        "items": {"type": "object", "properties": {"key": {"type": "string"}, "value": {"type": "string"}}},
                    },
                },
            },
        },
    },
}


def _status(name: str, level: Level, message: str, hardware_id: str, **values: Any) -> Status:
    return Status(level, name, message, hardware_id, tuple((key, "" if value is None else str(value)) for key, value in values.items()))


def _link(name: str, link: LinkHealth, hardware_id: str) -> Status:
    return _status(name, link_level(link.state), link.state, hardware_id, connected_since=link.connected_since, reconnects=link.reconnects)


def diagnostic_json(status: Status) -> dict[str, Any]:
    """One status as diagnostic_msgs/msg/DiagnosticStatus in JSON."""
    values = [{"key": key, "value": value} for key, value in status.values]
    return {"level": int(status.level), "name": status.name, "message": status.message, "hardware_id": status.hardware_id, "values": values}


def diagnostics(health: GatewayHealth, hardware_id: str) -> dict[str, Any]:
    """The gateway's health as a diagnostic_msgs/msg/DiagnosticArray (JSON): e-stop, links, commands, robot exchange.

    The levels are the shared table's (:mod:`blackmetal.runtime.diagnostics`), as on ROS 2 ``/diagnostics``.
    """
    sec, nsec = stamp_parts(health.stamp)
    driver = health.active_source or "nobody"
    if health.conflict_with:
        level, message = COMMANDS_REFUSED.check(other=health.conflict_with)
        command = _status("gateway: commands", level, message, hardware_id)
    else:
        command = _status(
            "gateway: commands",
            Level.OK,
            f"driven by {driver}",
            hardware_id,
            active_source=health.active_source,
            cmd_timeout_active=health.cmd_timeout_active,
            commands_sent=health.commands_sent,
            rejected_inputs=health.rejected_inputs,
            **{f"source {name}": f"priority {s.priority}, age {s.age}, dropped {s.dropped}" for name, s in health.sources.items()},
            **{f"lock {name}": engaged for name, engaged in health.locks.items()},
        )
    lost = health.lost_replies + health.malformed_replies
    statuses = [
        _status(
            "gateway: e-stop",
            ESTOP_ENGAGED.level if health.estop else Level.OK,
            health.estop_text(),
            hardware_id,
            estop=health.estop,
            estop_since=health.estop_since,
            estop_by=health.estop_by,
        ),
        _link("gateway: control link", health.control, hardware_id),
        _link("gateway: log link", health.log, hardware_id),
        command,
        _status(
            "gateway: robot exchange",
            REPLIES_LOST_EVER if lost else Level.OK,
            f"{health.poll_hz:g} Hz polls, rtt {health.last_rtt_ms} ms",
            hardware_id,
            polls=health.polls,
            replies=health.replies,
            lost_replies=health.lost_replies,
            malformed_replies=health.malformed_replies,
            full_buffer=health.full_buffer,
            wheel_speeds=health.wheel_speeds,
        ),
    ]
    status = [diagnostic_json(s) for s in statuses]
    return {"header": {"stamp": {"sec": sec, "nsec": nsec}, "frame_id": ""}, "status": status}


def timestamp(stamp: float) -> Any:
    from foxglove.messages import Timestamp

    sec, nsec = stamp_parts(stamp)
    return Timestamp(sec=sec, nsec=nsec)


def _pose(pose: Pose) -> Any:
    from foxglove.messages import Pose as FoxPose
    from foxglove.messages import Quaternion, Vector3

    q = pose.orientation
    return FoxPose(position=Vector3(x=pose.x, y=pose.y, z=0.0), orientation=Quaternion(x=q.x, y=q.y, z=q.z, w=q.w))


class Trail:
    """A bounded path of poses, sent at most every PATH_PERIOD_S."""

    def __init__(self, length: int) -> None:
        self.poses: deque[Pose] = deque(maxlen=length)
        self._last_sent = -1e18

    def add(self, pose: Pose) -> bool:
        """Add a pose; True when the path is due to be sent."""
        self.poses.append(pose)
        if pose.stamp - self._last_sent >= PATH_PERIOD_S or pose.stamp < self._last_sent:
            self._last_sent = pose.stamp
            return True
        return False


def json_channel(topic: str, schema: dict[str, Any]) -> Any:
    """A JSON channel on the current Foxglove context, its schema the JSON Schema ``schema`` (named by its title)."""
    import foxglove

    full = foxglove.Schema(name=schema["title"], encoding="jsonschema", data=json.dumps(schema).encode())
    return foxglove.Channel(topic, schema=full, message_encoding="json")


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
    """A channel on the current Foxglove context (the SDK's typed channels for Foxglove's types)."""
    from foxglove.channels import FrameTransformChannel, LogChannel, PoseInFrameChannel, PosesInFrameChannel

    typed: dict[Kind, Callable[[str], Any]] = {
        Kind.POSE: PoseInFrameChannel,
        Kind.POSES: PosesInFrameChannel,
        Kind.TRANSFORM: FrameTransformChannel,
        Kind.LOG: LogChannel,
    }
    if kind is Kind.JSON:
        assert schema is not None
        return cast(Out, json_channel(topic, schema))
    return cast(Out, typed[kind](topic))


def _transform(stamp: float, parent: str, child: str, xyz: tuple[float, float, float], q: tuple[float, float, float, float]) -> Any:
    from foxglove.messages import FrameTransform, Quaternion, Vector3

    return FrameTransform(
        timestamp=timestamp(stamp),
        parent_frame_id=parent,
        child_frame_id=child,
        translation=Vector3(x=xyz[0], y=xyz[1], z=xyz[2]),
        rotation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]),
    )


class LiveView:
    """The view's channels of one robot, and what each of its keys' payloads shows on them.

    Every handler first asks which of its channels anyone takes
    (``has_sinks``): a payload nobody watches is not even decoded, and only
    the watched channels' messages are built. :meth:`feeds` says which
    channels each key feeds, so the host subscribes to a key only while one
    of them is watched (:class:`~blackmetal.foxglove.watch.Watch`).
    """

    def __init__(
        self,
        keys: Keys,
        frame: str = "odom",
        base: str = "base_link",
        path_length: int = 2000,
        encoders: Encoders | None = None,
        namespace: str = "",
        tf: Out | None = None,
        frame_prefix: str = "",
        channel: ChannelFactory = foxglove_channel,
    ) -> None:
        """``namespace`` (``""`` or ``/<id>``) goes before every topic; ``tf``: a transform channel shared with other views
        (else ``<namespace>/tf``); ``frame_prefix`` (``""`` or ``<id>/``) before every link of the robot's URDF."""
        self.keys = keys
        self.namespace = namespace
        self.frame, self.base = frame, base
        self.model = RobotModel(frame_prefix, encoders)
        self._angles = WheelAngles()
        schemas = json_schemas()
        ns = namespace

        self.pose = channel(f"{ns}/pose", Kind.POSE, None)
        self.tf = tf if tf is not None else channel(f"{ns}/tf", Kind.TRANSFORM, None)
        self.tf_topic = "/tf" if tf is not None else f"{ns}/tf"
        self.path = channel(f"{ns}/path", Kind.POSES, None)
        self.truth = channel(f"{ns}/truth/pose", Kind.POSE, None)
        self.truth_path = channel(f"{ns}/truth/path", Kind.POSES, None)
        self.odometry = channel(f"{ns}/odometry", Kind.JSON, schemas["Pose"])
        self.wheels = channel(f"{ns}/wheels", Kind.JSON, WHEELS_SCHEMA)
        self.joint_states = channel(f"{ns}/joint_states", Kind.JSON, JOINT_STATE_SCHEMA)
        self.description = channel(f"{ns}/robot_description", Kind.JSON, STRING_SCHEMA)
        self.status = channel(f"{ns}/status", Kind.JSON, schemas["RobotStatus"])
        self.health = channel(f"{ns}/health", Kind.JSON, schemas["GatewayHealth"])
        self.diagnostics = channel(f"{ns}/diagnostics", Kind.JSON, DIAGNOSTICS_SCHEMA)
        self.errors = channel(f"{ns}/errors", Kind.JSON, schemas["ErrorReport"])
        self.log = channel(f"{ns}/log", Kind.LOG, None)
        self._trail = Trail(path_length)
        self._truth_trail = Trail(path_length)

    @property
    def description_topic(self) -> str:
        return f"{self.namespace}/robot_description"

    def feeds(self) -> dict[str, set[str]]:
        """Key -> the topics its payloads are shown on (the host subscribes to a key while one of them is watched)."""
        k, ns = self.keys, self.namespace
        return {
            k.pose: {f"{ns}/pose", self.tf_topic, f"{ns}/path", f"{ns}/odometry"},
            k.sim_truth: {f"{ns}/truth/pose", f"{ns}/truth/path"},
            k.impulses: {f"{ns}/wheels", f"{ns}/joint_states", self.tf_topic},
            k.status: {f"{ns}/status"},
            k.health: {f"{ns}/health", f"{ns}/diagnostics"},
            k.errors: {f"{ns}/errors", f"{ns}/log"},
        }

    def handlers(self) -> dict[str, Callable[[bytes], None]]:
        """Key -> handler of its payloads."""
        k = self.keys
        return {
            k.pose: self.on_pose,
            k.sim_truth: self.on_truth,
            k.impulses: self.on_impulses,
            k.status: self.on_status,
            k.health: self.on_health,
            k.errors: self.on_error,
        }

    def _decode(self, message_type: type[Any], payload: bytes) -> Any:
        try:
            return decode(message_type, payload)
        except PayloadError:
            return None

    def _poses(self, pose: Pose, channel: Out, path_channel: Out, trail: Trail) -> None:
        from foxglove.messages import PoseInFrame, PosesInFrame

        if channel.has_sinks():
            channel.log(PoseInFrame(timestamp=timestamp(pose.stamp), frame_id=self.frame, pose=_pose(pose)))
        if trail.add(pose) and path_channel.has_sinks():
            path_channel.log(PosesInFrame(timestamp=timestamp(pose.stamp), frame_id=self.frame, poses=[_pose(p) for p in trail.poses]))

    def on_pose(self, payload: bytes) -> None:
        wants = [self.pose.has_sinks(), self.path.has_sinks(), self.tf.has_sinks(), self.odometry.has_sinks()]
        if not any(wants):
            return
        pose = self._decode(Pose, payload)
        if pose is None:
            return
        self._poses(pose, self.pose, self.path, self._trail)
        if wants[2]:
            q = pose.orientation
            self.tf.log(_transform(pose.stamp, self.frame, self.base, (pose.x, pose.y, 0.0), (q.x, q.y, q.z, q.w)))
        if wants[3]:
            self.odometry.log(payload)

    def on_truth(self, payload: bytes) -> None:
        if not (self.truth.has_sinks() or self.truth_path.has_sinks()):
            return
        pose = self._decode(Pose, payload)
        if pose is not None:
            self._poses(pose, self.truth, self.truth_path, self._truth_trail)

    def on_status(self, payload: bytes) -> None:
        if self.status.has_sinks() and self._decode(RobotStatus, payload) is not None:
            self.status.log(payload)

    def on_health(self, payload: bytes) -> None:
        shows, diagnoses = self.health.has_sinks(), self.diagnostics.has_sinks()
        if not (shows or diagnoses):
            return
        health = self._decode(GatewayHealth, payload)
        if health is None:
            return
        if shows:
            self.health.log(payload)
        if diagnoses:
            self.diagnostics.log(json.dumps(diagnostics(health, self.keys.prefix)).encode())

    def on_impulses(self, payload: bytes) -> None:
        speeds, joints, turns = self.wheels.has_sinks(), self.joint_states.has_sinks(), self.tf.has_sinks()
        if not (speeds or joints or turns):
            return
        sample = self._decode(WheelImpulses, payload)
        if sample is None:
            return
        model = self.model
        self._angles.feed(sample, model.encoders, model.body.wheel_radius)
        if speeds:
            left, right = model.encoders.to_speeds(float(sample.left), float(sample.right))
            message = {
                "stamp": sample.stamp,
                "left_mps": left,
                "right_mps": right,
                "left_impulses": sample.left,
                "right_impulses": sample.right,
            }
            self.wheels.log(json.dumps(message).encode())
        if joints:
            self.joint_states.log(json.dumps(joint_state(model, self._angles, sample.stamp)).encode())
        if turns:
            for joint, angle in ((model.left, self._angles.positions[0]), (model.right, self._angles.positions[1])):
                if joint is not None:
                    xyz, q = turned(joint, angle)
                    self.tf.log(_transform(sample.stamp, joint.parent, joint.child, xyz, q))

    def on_error(self, payload: bytes) -> None:
        from foxglove.messages import Log, LogLevel

        shows, logs = self.errors.has_sinks(), self.log.has_sinks()
        if not (shows or logs):
            return
        report = self._decode(ErrorReport, payload)
        if report is None:
            return
        if shows:
            self.errors.log(payload)
        if logs:
            self.log.log(
                Log(timestamp=timestamp(report.stamp), level=LogLevel.Warning, message=f"{report.key}: {report.reason}", name=report.source)
            )

    def on_params(self, params: GatewayParams) -> None:
        """The gateway's parameters: a new wheel geometry re-sends the URDF to whoever shows it."""
        if self.model.on_params(params):
            self.describe()

    def describe(self) -> None:
        """Send the URDF on ``/robot_description`` (to every subscriber: on a new subscription, and when it changes)."""
        if self.description.has_sinks():
            self.description.log(self.model.description())


# --------------------------------------------------------------------------- what clients may do

#: The command source the view's clients drive as (``<prefix>/cmd_vel/foxglove``).
COMMAND_SOURCE = Sources.FOXGLOVE
#: The one message encoding clients may publish and call services in.
CLIENT_ENCODING = "json"
#: A set_estop call re-sends its engage and asks the gateway's health this often (s) until confirmed.
ASK_PERIOD_S = 0.2
#: A refused client channel gets at most one status message this often (s); every refusal is still counted in reports.
STATUS_PERIOD_S = 1.0
RELEASE_HINT = 'only {"data": false} releases the e-stop'


class Control(Enum):
    """The topics a client may publish on."""

    CMD_VEL = "/cmd_vel"
    ESTOP = "/estop"


#: The schema names a client may advertise each control topic with (ROS 2 and ROS 1 spellings).
CONTROL_SCHEMAS: dict[Control, tuple[str, ...]] = {
    Control.CMD_VEL: ("geometry_msgs/msg/Twist", "geometry_msgs/Twist"),
    Control.ESTOP: ("std_msgs/msg/Bool", "std_msgs/Bool"),
}


class Service(Enum):
    """The services the view offers."""

    SET_ESTOP = "set_estop"
    RESET_ODOMETRY = "reset_odometry"


# --------------------------------------------------------------------------- names: one robot, or a robot of a fleet
def robot_namespace(robot_id: str) -> str:
    """The topics of a fleet's robot go under ``/<id>`` (``/r3/odometry``); one robot's view has none (``""``)."""
    return f"/{robot_id}"


def robot_frame(robot_id: str, frame: str) -> str:
    """A fleet's robot's frame, prefixed as ``ros2 --fleet`` (diff_drive_controller) prefixes it: ``r3/odom``, ``r3/base_link``."""
    return f"{robot_id}/{frame}"


def control_topic(namespace: str, control: Control) -> str:
    """The topic a client publishes ``control`` on: ``/cmd_vel``, or ``/r3/cmd_vel`` in the namespace ``/r3``."""
    return f"{namespace}{control.value}"


def service_name(namespace: str, service: Service) -> str:
    """The name ``service`` is advertised under: ``set_estop`` for one robot, ``/r3/set_estop`` for a fleet's (as ROS names it)."""
    return f"{namespace}/{service.value}" if namespace else service.value


def takes(namespace: str = "") -> str:
    """What clients may publish, for refusals and the startup lines."""
    return " and ".join(f"{control_topic(namespace, c)} ({CONTROL_SCHEMAS[c][0]})" for c in Control) + ", JSON-encoded"


def robot_of(name: str, robot_ids: Collection[str]) -> str | None:
    """The robot a fleet topic or service name belongs to (``/r3/cmd_vel`` -> ``r3``), None when it names none of ``robot_ids``."""
    head, slash, rest = name.removeprefix("/").partition("/")
    return head if name.startswith("/") and slash and rest and head in robot_ids else None


TAKES = takes()


class RosBool(msgspec.Struct, forbid_unknown_fields=True):
    """std_msgs/msg/Bool and the std_srvs/srv/SetBool request, as JSON: ``{"data": true}``."""

    data: bool


def _object(properties: dict[str, Any], required: list[str] | None = None) -> dict[str, Any]:
    return {"type": "object", "properties": properties, "required": required or [], "additionalProperties": False}


_NUMBER = {"type": "number"}
_QUATERNION_SCHEMA = _object({name: _NUMBER for name in ("x", "y", "z", "w")})
_POSE_SCHEMA = _object({**{name: _NUMBER for name in ("stamp", "x", "y", "yaw", "v", "w")}, "orientation": _QUATERNION_SCHEMA})


@dataclass(frozen=True, slots=True)
class ServiceSpec:
    """A service as the protocol advertises it: its type, and the JSON Schemas (titled with their names) of request and response."""

    type: str
    request: dict[str, Any]
    response: dict[str, Any]


SERVICE_SPECS: dict[Service, ServiceSpec] = {
    Service.SET_ESTOP: ServiceSpec(
        "std_srvs/srv/SetBool",
        {"title": "std_srvs/srv/SetBool_Request", **_object({"data": {"type": "boolean"}}, ["data"])},
        {"title": "std_srvs/srv/SetBool_Response", **_object({"success": {"type": "boolean"}, "message": {"type": "string"}})},
    ),
    Service.RESET_ODOMETRY: ServiceSpec(
        "blackmetal/srv/ResetOdometry",
        {"title": "blackmetal/srv/ResetOdometry_Request", **_object({"x": _NUMBER, "y": _NUMBER, "yaw": _NUMBER})},
        {
            "title": "blackmetal/srv/ResetOdometry_Response",
            **_object({"success": {"type": "boolean"}, "message": {"type": "string"}, "pose": _POSE_SCHEMA}),
        },
    ),
}


class StatusLevel(IntEnum):
    """A status message's level in the Foxglove WebSocket protocol."""

    INFO = 0
    WARNING = 1
    ERROR = 2


class ServerRefusal(Enum):
    """What the WebSocket server itself sent a client when it refused something (the view saw it go out)."""

    STATUS = "status"
    SERVICE_CALL_FAILURE = "serviceCallFailure"


class ControlsOutput(Protocol):
    """Where :class:`Controls` sends what it decides: the robot's keys, the clients, the error reports."""

    def command(self, key: str, payload: bytes) -> None: ...
    def ask_health(self) -> None: ...
    def ask_reset(self, call: int, payload: bytes) -> None: ...
    def status(self, client: int | None, level: StatusLevel, message: str) -> None: ...
    def answer(self, call: int, response: bytes | None, failure: str | None) -> None: ...
    def error(self, message: ErrorReport) -> None: ...


@dataclass(slots=True)
class ClientTopic:
    """A channel a client advertised: what it controls, or why its messages are refused."""

    topic: str
    control: Control | None
    refusal: str | None
    drove: bool = False


@dataclass(slots=True)
class EstopCall:
    """A set_estop call waiting for the gateway's health to show ``engage``."""

    client: int
    engage: bool
    deadline: float
    next_ask: float


@dataclass(slots=True)
class ResetCall:
    """A reset_odometry call waiting for the odometry's answer."""

    client: int
    deadline: float


def _state(engage: bool) -> str:
    return "engaged" if engage else "released"


class Controls:
    """Client publications and service calls -> the robot's keys, with confirmations and refusals; see the module docstring.

    Clients are the WebSocket server's client ids; ``call`` numbers service
    calls (the host's numbering, unique while the view runs).
    """

    def __init__(
        self,
        keys: Keys,
        output: ControlsOutput,
        call_timeout: float = 2.0,
        wallclock: Callable[[], float] = time.time,
        namespace: str = "",
    ) -> None:
        self.keys = keys
        #: ``""``, or ``/<id>`` for a fleet's robot: it takes ``/<id>/cmd_vel``, ``/<id>/estop``, ``/<id>/set_estop``, ...
        self.namespace = namespace
        self._controls = {control_topic(namespace, c): c for c in Control}
        self._services = {service_name(namespace, s): s for s in Service}
        self.output = output
        self.call_timeout = call_timeout
        self.reporter = ErrorReporter("foxglove", output.error, wallclock)
        self.cmd_vel_key = keys.cmd_vel_of(COMMAND_SOURCE)
        self._topics: dict[tuple[int, int], ClientTopic] = {}
        self._estop_calls: dict[int, EstopCall] = {}
        self._reset_calls: dict[int, ResetCall] = {}
        self._last_status: dict[tuple[int | None, str], float] = {}
        #: The e-stop state in the gateway's last health (None: no health seen yet).
        self.estop_seen: bool | None = None

    # --------------------------------------------------------------- client publish
    def on_advertise(self, client: int, channel: int, topic: str, encoding: str, schema_name: str, now: float) -> None:
        """A client advertised a channel: note what it controls, or refuse it at once (status and report)."""
        control = self._controls.get(topic)
        refusal = None
        if control is None:
            refusal = f"topic {topic!r} is not taken here: clients publish {takes(self.namespace)}"
        elif encoding != CLIENT_ENCODING:
            refusal = f"{topic} must be {CLIENT_ENCODING}-encoded, not {encoding!r}"
        elif schema_name and schema_name not in CONTROL_SCHEMAS[control]:
            refusal = f"{topic} carries {' or '.join(CONTROL_SCHEMAS[control])}, not {schema_name!r}"
        self._topics[(client, channel)] = ClientTopic(topic, control, refusal)
        if refusal is not None:
            self._refuse(client, topic, f"{refusal}; its messages are refused", "", now)

    def on_unadvertise(self, client: int, channel: int, now: float) -> None:
        """A client stopped publishing on a channel: a /cmd_vel that drove sends one zero command, so the robot stops now rather than at the timeout."""
        topic = self._topics.pop((client, channel), None)
        if topic is not None and topic.control is Control.CMD_VEL and topic.drove:
            self.output.command(self.cmd_vel_key, encode(Twist()))

    def on_client_gone(self, client: int, now: float) -> None:
        """A client disconnected: its channels are unadvertised."""
        for key in [key for key in self._topics if key[0] == client]:
            self.on_unadvertise(client, key[1], now)
        for status_key in [key for key in self._last_status if key[0] == client]:
            del self._last_status[status_key]

    def on_message(self, client: int, channel: int, data: bytes, now: float) -> None:
        """One message a client published: a command, an e-stop, or a refusal (status to that client, report)."""
        topic = self._topics.get((client, channel))
        if topic is None:
            self._refuse(client, f"channel {channel}", f"channel {channel} was not advertised by this client", excerpt(data), now)
            return
        if topic.refusal is not None:
            self._refuse(client, topic.topic, topic.refusal, excerpt(data), now)
            return
        if topic.control is Control.CMD_VEL:
            try:
                twist = decode(Twist, data)
            except PayloadError as exc:
                self._refuse(client, topic.topic, f"{exc}; nothing was sent to the robot", exc.excerpt, now)
                return
            topic.drove = True
            self.output.command(self.cmd_vel_key, encode(twist))
        elif topic.control is Control.ESTOP:
            try:
                wish = decode(RosBool, data)
            except PayloadError as exc:
                self._estop(True, now)  # fails safe, as the gateway does: whoever published here meant the stop
                self._refuse(client, topic.topic, f"{exc}: the e-stop is engaged; {RELEASE_HINT}", exc.excerpt, now)
                return
            self._estop(wish.data, now)

    def _estop(self, engage: bool, now: float, call: int | None = None) -> None:
        """Put the e-stop; a pending set_estop call that wants the other state is superseded (its re-sends would undo this)."""
        self.output.command(self.keys.estop_for(engage), encode(EStop(engaged=engage)))
        for other, pending in list(self._estop_calls.items()):
            if other != call and pending.engage != engage:
                self._fail(
                    other, pending.client, Service.SET_ESTOP, f"superseded: the e-stop was {_state(engage)} since this call", "", now
                )

    def _refuse(self, client: int | None, topic: str, reason: str, text: str, now: float) -> None:
        """A status message to that client (at most once per STATUS_PERIOD_S per topic) and a report (rate-limited)."""
        last = self._last_status.get((client, topic), -math.inf)
        if now - last >= STATUS_PERIOD_S:
            self._last_status[(client, topic)] = now
            self.output.status(client, StatusLevel.ERROR, f"blackmetal refused a message on {topic}: {reason}")
        self.reporter.report(f"foxglove:{topic}", f"client {client}: {reason}", text, now=now)

    # --------------------------------------------------------------- services
    def on_service_call(self, call: int, client: int, service: str, payload: bytes, now: float) -> None:
        """A service call; it is answered later through ``output.answer``: on confirmation, failure or at the time limit."""
        known = self._services.get(service)
        if known is Service.SET_ESTOP:
            try:
                wish = decode(RosBool, payload)
            except PayloadError as exc:
                self._estop(True, now)
                self._fail(call, client, known, f"{exc}: the e-stop is engaged; {RELEASE_HINT}", exc.excerpt, now)
                return
            self._estop_calls[call] = EstopCall(client, wish.data, now + self.call_timeout, now + ASK_PERIOD_S)
            self._estop(wish.data, now, call)
            self.output.ask_health()  # asked after the put: the gateway takes its e-stop samples first
        elif known is Service.RESET_ODOMETRY:
            try:
                target = PoseReset() if not payload.strip() else decode(PoseReset, payload)
            except PayloadError as exc:
                self._fail(call, client, known, f"{exc}; the odometry was not reset", exc.excerpt, now)
                return
            self._reset_calls[call] = ResetCall(client, now + self.call_timeout)
            self.output.ask_reset(call, encode(target))
        else:
            self.output.answer(call, None, f"unknown service {service!r}: this view offers {', '.join(self._services)}")
            self.reporter.report(f"foxglove:{service}", f"client {client}: unknown service", excerpt(payload), now=now)

    def on_health(self, payload: bytes, now: float) -> None:
        """The gateway's health (published or asked for): it confirms the set_estop calls that wanted what it shows."""
        try:
            health = decode(GatewayHealth, payload)
        except PayloadError:
            return  # the gateway's own key: the view shows what it can, the gateway reports its own
        self.estop_seen = health.estop
        for call, pending in list(self._estop_calls.items()):
            if pending.engage == health.estop:
                del self._estop_calls[call]
                message = f"e-stop {_state(health.estop)} (confirmed by the gateway's health)"
                self.output.answer(call, json.dumps({"success": True, "message": message}).encode(), None)

    def on_reset_reply(self, call: int, ok: bytes | None, err: bytes | None, now: float) -> None:
        """The odometry's answer to a reset: its pose, or its reason for refusing."""
        pending = self._reset_calls.pop(call, None)
        if pending is None:
            return
        if ok is None:
            reason = (err or b"").decode("utf-8", errors="replace") or "no reason given"
            self._fail(call, pending.client, Service.RESET_ODOMETRY, f"the odometry refused the reset: {reason}", "", now)
            return
        try:
            pose = decode(Pose, ok)
        except PayloadError as exc:
            self._fail(
                call, pending.client, Service.RESET_ODOMETRY, f"the odometry answered something else than a pose: {exc}", exc.excerpt, now
            )
            return
        message = f"odometry reset to x={pose.x:g} y={pose.y:g} yaw={pose.yaw:g} (confirmed by the odometry)"
        self.output.answer(call, msgspec.json.encode({"success": True, "message": message, "pose": pose}), None)

    def on_reset_done(self, call: int, now: float) -> None:
        """The reset's query ended: a call still waiting got no answer at all."""
        pending = self._reset_calls.pop(call, None)
        if pending is not None:
            reason = f"no odometry answered on {self.keys.odometry_reset}: is blackmetal odometry running on prefix {self.keys.prefix!r}?"
            self._fail(call, pending.client, Service.RESET_ODOMETRY, reason, "", now)

    def _fail(self, call: int, client: int, service: Service, reason: str, text: str, now: float) -> None:
        self._estop_calls.pop(call, None)
        self._reset_calls.pop(call, None)
        self.output.answer(call, None, reason)
        self.reporter.report(f"foxglove:{service_name(self.namespace, service)}", f"client {client}: {reason}", text, now=now)

    # --------------------------------------------------------------- refusals the server made itself
    def on_server_refusal(self, client: int | None, kind: ServerRefusal, message: str, now: float) -> None:
        """The WebSocket server refused a client's message itself (bad JSON, unknown channel or service...): report it.

        A status message already told the client; a service call failure is
        followed by a status message, so the refusal shows where the client
        shows its problems.
        """
        if kind is ServerRefusal.SERVICE_CALL_FAILURE:
            self.output.status(client, StatusLevel.ERROR, f"blackmetal refused a service call: {message}")
        self.reporter.report("foxglove:client", f"client {client}: {message}", now=now)

    # --------------------------------------------------------------- timers
    def tick(self, now: float) -> None:
        """Time limits of the waiting calls, the set_estop engage re-sent and health asked again, report summaries."""
        for call, pending in list(self._estop_calls.items()):
            if now >= pending.deadline:
                seen = (
                    "no health from the gateway" if self.estop_seen is None else f"its health says the e-stop is {_state(self.estop_seen)}"
                )
                reason = (
                    f"the gateway did not confirm the e-stop {_state(pending.engage)} within {self.call_timeout:g} s ({seen}); "
                    f"is blackmetal gateway running on prefix {self.keys.prefix!r}?"
                )
                self._fail(call, pending.client, Service.SET_ESTOP, reason, "", now)
            elif now >= pending.next_ask:
                pending.next_ask = now + ASK_PERIOD_S
                if pending.engage:  # an engage is safe to repeat; a release is sent once, never over someone's later stop
                    self.output.command(self.keys.estop, encode(EStop(engaged=True)))
                self.output.ask_health()
        for call, reset in list(self._reset_calls.items()):
            if now >= reset.deadline:
                reason = f"the odometry did not answer within {self.call_timeout:g} s on {self.keys.odometry_reset}"
                self._fail(call, reset.client, Service.RESET_ODOMETRY, reason, "", now)
        self.reporter.tick(now)

    def next_deadline(self) -> float:
        deadlines = [self.reporter.next_deadline()]
        deadlines += [min(p.deadline, p.next_ask) for p in self._estop_calls.values()]
        deadlines += [p.deadline for p in self._reset_calls.values()]
        return min(deadlines)

    @property
    def waiting(self) -> int:
        """Service calls not answered yet."""
        return len(self._estop_calls) + len(self._reset_calls)


# --------------------------------------------------------------------------- a fleet in one view
#: The fleet's own topics (``/fleet/summary``, ``/fleet/log``): a robot may not have this id in the fleet view.
FLEET_NAMESPACE = "/fleet"
#: A robot whose gateway's health (published once a second) has not arrived for this long (s, the view's clock) is lost.
LOST_AFTER_S = 2.5
#: The fleet summary goes out at most this often on health alone (s); a robot lost or back sends it at once.
SUMMARY_PERIOD_S = 1.0

FLEET_SUMMARY_SCHEMA: dict[str, Any] = {
    "title": "FleetSummary",
    "description": "blackmetal: one row per robot of the fleet, from each <prefix>/gateway/health, its liveliness and <prefix>/pose",
    "type": "object",
    "properties": {
        "stamp": {"type": "number", "description": "the newest health's stamp"},
        "robots_up": {"type": "integer", "description": "robots with a fresh health and both links connected"},
        "lost": {"type": "array", "items": {"type": "string"}, "description": "ids of the robots lost (no health, or its gateway gone)"},
        "estop": {"type": "array", "items": {"type": "string"}, "description": "ids of the robots whose e-stop is engaged"},
        "driving": {"type": "object", "additionalProperties": {"type": "string"}, "description": "id -> the command source that drives it"},
        "robots": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "id": {"type": "string"},
                    "prefix": {"type": "string"},
                    "link": {"type": "string", "description": "control/log link states, 'no health', or 'lost: <why>'"},
                    "health_age": {"type": ["number", "null"], "description": "s since its last health arrived"},
                    "poll_hz": {"type": "number"},
                    "estop": {"type": ["boolean", "null"]},
                    "active_source": {"type": ["string", "null"], "description": "who drives (null: nobody)"},
                    "conflict_with": {"type": ["string", "null"]},
                    "x": {"type": ["number", "null"]},
                    "y": {"type": ["number", "null"]},
                    "yaw": {"type": ["number", "null"]},
                },
            },
        },
    },
}


@dataclass(slots=True)
class RobotRow:
    """What the fleet summary knows of one robot: its last health (and when it arrived), its pose, its gateway's token."""

    id: str
    prefix: str
    health: GatewayHealth | None = None
    pose: Pose | None = None
    #: When its last health arrived (the view's clock); None: none since the summary was last watched.
    seen: float | None = None
    #: Its gateway's liveliness token: present, gone, or not known yet.
    token: bool | None = None
    #: Why it is lost ("" while it is not).
    lost: str = ""


class Change(Enum):
    LOST = "lost"
    BACK = "back"


@dataclass(frozen=True, slots=True)
class Presence:
    """A robot lost or back, and why: what the fleet's log says and why the summary goes out at once."""

    robot_id: str
    change: Change
    reason: str


class FleetSummary:
    """The fleet at a glance, one row per robot; pure, on the view's clock (``now``, passed in).

    A robot is **lost** when its gateway's liveliness token goes, or when no
    health of it has arrived for :data:`LOST_AFTER_S` (its host dropped off:
    the token lingers until the router's lease ends), and **back** with its
    next health. Health is followed only while someone watches the summary
    or the fleet's log (the host subscribes then); :meth:`suspend` forgets
    the arrival times when nobody does, so no robot is called lost for a
    silence nobody listened to.
    """

    def __init__(self, robots: list[tuple[str, str]]) -> None:
        """``robots``: (id, prefix) in the fleet file's order."""
        self.rows = {robot_id: RobotRow(robot_id, prefix) for robot_id, prefix in robots}
        self._newest = -math.inf

    def _lose(self, row: RobotRow, reason: str) -> Presence | None:
        if row.lost:
            return None
        row.lost = reason
        return Presence(row.id, Change.LOST, reason)

    def on_health(self, robot_id: str, health: GatewayHealth, now: float) -> Presence | None:
        row = self.rows[robot_id]
        row.health, row.seen = health, now
        self._newest = max(self._newest, health.stamp)
        if row.lost:
            row.lost = ""
            return Presence(robot_id, Change.BACK, "its gateway's health arrives again")
        return None

    def on_token(self, robot_id: str, alive: bool, now: float) -> Presence | None:
        """Its gateway's liveliness token appeared or went: gone is lost at once; present waits for a health."""
        row = self.rows[robot_id]
        row.token = alive
        if not alive:
            row.seen = None
            return self._lose(row, "its gateway left (liveliness token gone)")
        return None

    def on_pose(self, robot_id: str, pose: Pose) -> None:
        self.rows[robot_id].pose = pose

    def tick(self, now: float) -> list[Presence]:
        """Robots whose health stopped arriving."""
        changes = []
        for row in self.rows.values():
            if row.seen is not None and now >= row.seen + LOST_AFTER_S:
                row.seen = None
                change = self._lose(row, f"no health for {LOST_AFTER_S:g} s")
                if change is not None:
                    changes.append(change)
        return changes

    def next_deadline(self) -> float:
        return min((row.seen + LOST_AFTER_S for row in self.rows.values() if row.seen is not None), default=math.inf)

    def suspend(self) -> None:
        """Nobody follows the robots' health any more: forget when it last came (losses by token stay)."""
        for row in self.rows.values():
            row.seen = None

    def message(self, now: float) -> dict[str, Any]:
        rows = []
        for row in self.rows.values():
            h, p = row.health, row.pose
            age = None if row.seen is None else max(now - row.seen, 0.0)
            if row.lost:
                link = f"lost: {row.lost}"
            elif h is None or row.seen is None:
                link = "no health"
            else:
                link = f"{h.control.state}/{h.log.state}"
            fresh = h is not None and not row.lost and row.seen is not None
            rows.append(
                {
                    "id": row.id,
                    "prefix": row.prefix,
                    "link": link,
                    "health_age": age,
                    "poll_hz": h.poll_hz if fresh and h is not None else 0.0,
                    "estop": None if h is None else h.estop,
                    "active_source": h.active_source if fresh and h is not None else None,
                    "conflict_with": None if h is None else h.conflict_with,
                    "x": None if p is None else p.x,
                    "y": None if p is None else p.y,
                    "yaw": None if p is None else p.yaw,
                }
            )
        return {
            "stamp": self._newest if self._newest > -math.inf else 0.0,
            "robots_up": sum(1 for r in rows if r["link"] == "connected/connected"),
            "lost": [row.id for row in self.rows.values() if row.lost],
            "estop": [r["id"] for r in rows if r["estop"]],
            "driving": {r["id"]: r["active_source"] for r in rows if r["active_source"]},
            "robots": rows,
        }


class FleetView:
    """One :class:`LiveView` per robot under ``/<id>/``, frames ``<id>/odom`` -> ``<id>/base_link`` on one ``/tf``,
    each robot's URDF with its links under ``<id>/``, ``/fleet/summary`` and ``/fleet/log``.

    The summary is on the view's clock (``clock``, the host's): it goes out
    at most every :data:`SUMMARY_PERIOD_S` on health, and at once when a
    robot is lost or back (:meth:`tick` at :meth:`next_deadline` finds the
    silent ones), with a line on ``/fleet/log``. Its poses are the latest
    each robot published, read when it is made (``poses``), never a stream.
    """

    def __init__(
        self,
        robots: list[tuple[str, Keys, Encoders | None, int]],
        clock: Callable[[], float] = time.monotonic,
        channel: ChannelFactory = foxglove_channel,
        poses: Callable[[str], bytes | None] = lambda robot_id: None,
    ) -> None:
        """``robots``: (id, keys, its encoders or None for the defaults, its path length), in the fleet file's order;
        ``poses(id)``: the robot's latest pose payload, if the host holds one."""
        self.clock = clock
        self.poses = poses
        self.tf = channel("/tf", Kind.TRANSFORM, None)  # one tree for the fleet, as ros2 --fleet sends every robot's to the absolute /tf
        self.views = {
            robot_id: LiveView(
                keys,
                frame=robot_frame(robot_id, "odom"),
                base=robot_frame(robot_id, "base_link"),
                path_length=path_length,
                encoders=encoders,
                namespace=robot_namespace(robot_id),
                tf=self.tf,
                frame_prefix=robot_frame(robot_id, ""),
                channel=channel,
            )
            for robot_id, keys, encoders, path_length in robots
        }
        self.summary = FleetSummary([(robot_id, keys.prefix) for robot_id, keys, _, _ in robots])
        self.summary_channel = channel(f"{FLEET_NAMESPACE}/summary", Kind.JSON, FLEET_SUMMARY_SCHEMA)
        #: Robots lost and back, and refusals of client messages that name no robot (a topic outside every /<id>/, the server's own).
        self.log = channel(f"{FLEET_NAMESPACE}/log", Kind.LOG, None)
        self._last_summary = -math.inf

    @property
    def fleet_topics(self) -> set[str]:
        """The topics that follow every robot's health (and so the robots lost and back)."""
        return {f"{FLEET_NAMESPACE}/summary", f"{FLEET_NAMESPACE}/log"}

    def feeds(self) -> dict[str, set[str]]:
        """Every robot's keys -> the topics they feed; each health also feeds the summary and the fleet's log."""
        feeds: dict[str, set[str]] = {}
        for view in self.views.values():
            for key, topics in view.feeds().items():
                feeds.setdefault(key, set()).update(topics)
            feeds[view.keys.health] |= self.fleet_topics
        return feeds

    def peeks(self) -> dict[str, set[str]]:
        """Keys the summary reads the latest of when it is made (no stream): every robot's pose."""
        return {view.keys.pose: {f"{FLEET_NAMESPACE}/summary"} for view in self.views.values()}

    def handlers(self, robot_id: str) -> dict[str, Callable[[bytes], None]]:
        """Key -> handler for one robot's keys: its own view, and the summary from its health."""
        view = self.views[robot_id]
        handlers = view.handlers()
        show_health = handlers[view.keys.health]

        def on_health(payload: bytes) -> None:
            show_health(payload)
            if not (self.summary_channel.has_sinks() or self.log.has_sinks()):
                return
            health = view._decode(GatewayHealth, payload)
            if health is None:
                return
            now = self.clock()
            change = self.summary.on_health(robot_id, health, now)
            if change is not None or now >= self._last_summary + SUMMARY_PERIOD_S:
                self._changed([change] if change is not None else [], now)

        handlers[view.keys.health] = on_health
        return handlers

    def on_token(self, robot_id: str, alive: bool) -> None:
        """Its gateway's liveliness token appeared or went."""
        now = self.clock()
        change = self.summary.on_token(robot_id, alive, now)
        if change is not None:
            self._changed([change], now)

    def tick(self, now: float) -> None:
        changes = self.summary.tick(now)
        if changes:
            self._changed(changes, now)

    def next_deadline(self) -> float:
        return self.summary.next_deadline()

    def suspend(self) -> None:
        """Nobody watches the summary or the fleet's log: the host stops following health."""
        self.summary.suspend()

    def _changed(self, changes: list[Presence], now: float) -> None:
        from foxglove.messages import Log, LogLevel

        if self.log.has_sinks():
            for change in changes:
                level = LogLevel.Error if change.change is Change.LOST else LogLevel.Info
                self.log.log(
                    Log(
                        timestamp=timestamp(time.time()),
                        level=level,
                        message=f"{change.robot_id} {change.change.value}: {change.reason}",
                        name="fleet",
                    )
                )
        if self.summary_channel.has_sinks():
            for robot_id, view in self.views.items():
                payload = self.poses(robot_id)
                pose = view._decode(Pose, payload) if payload is not None else None
                if pose is not None:
                    self.summary.on_pose(robot_id, pose)
            self._last_summary = now
            self.summary_channel.log(json.dumps(self.summary.message(now)).encode())

    def on_fleet_error(self, report: ErrorReport) -> None:
        """A refusal no robot owns: on ``/fleet/log``."""
        from foxglove.messages import Log, LogLevel

        self.log.log(
            Log(timestamp=timestamp(report.stamp), level=LogLevel.Warning, message=f"{report.key}: {report.reason}", name=report.source)
        )


class FleetOutput(Protocol):
    """Where :class:`FleetControls` sends what no robot's :class:`Controls` owns."""

    def status(self, client: int | None, level: StatusLevel, message: str) -> None: ...
    def answer(self, call: int, response: bytes | None, failure: str | None) -> None: ...


class FleetControls:
    """One :class:`Controls` per robot (namespace ``/<id>``), each fed only what names its robot; the rest is refused here.

    A client's channel on ``/r3/...`` and a call of ``/r3/...`` go to r3's
    controls alone, which act on r3's prefix and report on r3's errors key;
    a topic outside every robot's namespace (or a refusal of the server
    itself, which names no robot) is refused with a status to that client
    and reported on ``fleet_error`` (the fleet's log), never on a robot's key.
    """

    def __init__(
        self,
        robots: dict[str, Controls],
        output: FleetOutput,
        fleet_error: Callable[[ErrorReport], None],
        wallclock: Callable[[], float] = time.time,
    ) -> None:
        self.robots = robots
        self.output = output
        self.reporter = ErrorReporter("foxglove", fleet_error, wallclock)
        #: (client, channel) -> the robot it names, or None with the topic it refused.
        self._channels: dict[tuple[int, int], tuple[str | None, str]] = {}
        self._last_status: dict[tuple[int | None, str], float] = {}

    def _takes(self) -> str:
        return f"{takes('/<id>')} for the robots {', '.join(self.robots)}"

    def _refuse(self, client: int | None, topic: str, reason: str, text: str, now: float) -> None:
        last = self._last_status.get((client, topic), -math.inf)
        if now - last >= STATUS_PERIOD_S:
            self._last_status[(client, topic)] = now
            self.output.status(client, StatusLevel.ERROR, f"blackmetal refused a message on {topic}: {reason}")
        self.reporter.report(f"foxglove:{topic}", f"client {client}: {reason}", text, now=now)

    def on_advertise(self, client: int, channel: int, topic: str, encoding: str, schema_name: str, now: float) -> None:
        robot_id = robot_of(topic, self.robots)
        self._channels[(client, channel)] = (robot_id, topic)
        if robot_id is not None:
            self.robots[robot_id].on_advertise(client, channel, topic, encoding, schema_name, now)
        else:
            self._refuse(
                client, topic, f"topic {topic!r} is not taken here: clients publish {self._takes()}; its messages are refused", "", now
            )

    def on_unadvertise(self, client: int, channel: int, now: float) -> None:
        robot_id, _ = self._channels.pop((client, channel), (None, ""))
        if robot_id is not None:
            self.robots[robot_id].on_unadvertise(client, channel, now)

    def on_client_gone(self, client: int, now: float) -> None:
        for key in [key for key in self._channels if key[0] == client]:
            self.on_unadvertise(client, key[1], now)
        for status_key in [key for key in self._last_status if key[0] == client]:
            del self._last_status[status_key]
        for controls in self.robots.values():
            controls.on_client_gone(client, now)

    def on_message(self, client: int, channel: int, data: bytes, now: float) -> None:
        known = self._channels.get((client, channel))
        if known is None:
            self._refuse(client, f"channel {channel}", f"channel {channel} was not advertised by this client", excerpt(data), now)
        elif known[0] is None:
            self._refuse(client, known[1], f"topic {known[1]!r} is not taken here: clients publish {self._takes()}", excerpt(data), now)
        else:
            self.robots[known[0]].on_message(client, channel, data, now)

    def on_service_call(self, call: int, client: int, service: str, payload: bytes, now: float) -> None:
        robot_id = robot_of(service, self.robots)
        if robot_id is not None:
            self.robots[robot_id].on_service_call(call, client, service, payload, now)
            return
        offered = ", ".join(service_name(robot_namespace("<id>"), s) for s in Service)
        self.output.answer(call, None, f"unknown service {service!r}: this view offers {offered} for the robots {', '.join(self.robots)}")
        self.reporter.report(f"foxglove:{service}", f"client {client}: unknown service", excerpt(payload), now=now)

    def on_health(self, robot_id: str, payload: bytes, now: float) -> None:
        self.robots[robot_id].on_health(payload, now)

    def on_reset_reply(self, robot_id: str, call: int, ok: bytes | None, err: bytes | None, now: float) -> None:
        self.robots[robot_id].on_reset_reply(call, ok, err, now)

    def on_reset_done(self, robot_id: str, call: int, now: float) -> None:
        self.robots[robot_id].on_reset_done(call, now)

    def on_server_refusal(self, client: int | None, kind: ServerRefusal, message: str, now: float) -> None:
        """The server refused a message itself: it names no robot, so it is reported on the fleet's log."""
        if kind is ServerRefusal.SERVICE_CALL_FAILURE:
            self.output.status(client, StatusLevel.ERROR, f"blackmetal refused a service call: {message}")
        self.reporter.report("foxglove:client", f"client {client}: {message}", now=now)

    def tick(self, now: float) -> None:
        for controls in self.robots.values():
            controls.tick(now)
        self.reporter.tick(now)

    def next_deadline(self) -> float:
        return min([self.reporter.next_deadline(), *(c.next_deadline() for c in self.robots.values())])

    @property
    def waiting(self) -> int:
        return sum(c.waiting for c in self.robots.values())
