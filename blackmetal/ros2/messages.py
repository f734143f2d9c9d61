"""ROS 2 messages as CDR bytes, both ways, with the ``rosbags`` package's Jazzy type store.

The adapter's whole contact with ROS types: blackmetal messages in, CDR
bytes out (``/odom``, ``/tf``, ``/joint_states``, ``/diagnostics``, service
responses), and CDR bytes in, blackmetal messages out (``/cmd_vel``,
``/estop``, service requests). Decoding is strict: a payload that is not
exactly one valid message of the expected type, or that carries a
non-finite number, is a :class:`PayloadError` saying why. Type hashes
(``RIHS01_...``) are computed by rosbags from the type definitions, never
copied by hand.

rosbags' store has no ``std_srvs``: the two services are registered here
from their ``.srv`` text, with the service-level type rosidl hashes
(``request_message``, ``response_message``, ``event_message``), and the
store's ``char`` fields are read as ``uint8``, as rosidl maps them (this
is what makes ``service_msgs/msg/ServiceEventInfo``, and so every service
hash, match ROS 2's).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

from blackmetal.schemas import EStop, PayloadError, Pose, Twist, Vector3, require_extra, stamp_parts

TWIST = "geometry_msgs/msg/Twist"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
JOINT_STATE = "sensor_msgs/msg/JointState"
BOOL = "std_msgs/msg/Bool"
STRING = "std_msgs/msg/String"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
SET_BOOL = "std_srvs/srv/SetBool"
TRIGGER = "std_srvs/srv/Trigger"

#: The services' .srv text (request, response), as std_srvs defines them; an empty request gets rosidl's placeholder.
SERVICE_DEFINITIONS = {
    SET_BOOL: ("bool data", "bool success\nstring message"),
    TRIGGER: ("", "bool success\nstring message"),
}

#: CDR encapsulation headers ROS 2 writes: plain CDR, little- or big-endian.
CDR_HEADERS = (b"\x00\x01", b"\x00\x00")


def _store() -> Any:
    require_extra("blackmetal ros2", "ros2", "rosbags")
    require_extra("blackmetal ros2", "ros2", "xxhash")
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)  # a fresh store: what is changed below stays in it
    _char_is_uint8(store)
    _register_services(store)
    return store


def _char_is_uint8(store: Any) -> None:
    """rosidl maps a .msg ``char`` to ``uint8`` (same one byte in CDR); rosbags keeps ``char``, which changes the hashes."""
    from rosbags.typesys.base import Nodetype

    def fix(desc: Any) -> Any:
        kind, rest = desc
        if kind == Nodetype.BASE and rest[0] == "char":
            return (kind, ("uint8", rest[1]))
        if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            return (kind, (fix(rest[0]), rest[1]))
        return desc

    for name, (consts, fields) in list(store.fielddefs.items()):
        store.fielddefs[name] = (consts, [(fname, fix(desc)) for fname, desc in fields])


def _register_services(store: Any) -> None:
    """``<srv>_Request``, ``_Response``, ``_Event`` and the service type itself, as rosidl describes a service."""
    from rosbags.typesys import get_types_from_msg
    from rosbags.typesys.base import Nodetype

    def name_of(typename: str) -> str:  # rosbags reads "pkg/srv/Name" as "pkg/srv/msg/Name"
        return typename.replace("/srv/msg/", "/srv/")

    def fix(desc: Any) -> Any:
        kind, rest = desc
        if kind == Nodetype.NAME:
            return (kind, name_of(rest))
        if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            return (kind, (fix(rest[0]), rest[1]))
        return desc

    types: dict[str, Any] = {}

    def add(typename: str, text: str) -> None:
        for name, (consts, fields) in get_types_from_msg(text, typename).items():
            types[name_of(name)] = (consts, [(fname, fix(desc)) for fname, desc in fields])

    for service, (request, response) in SERVICE_DEFINITIONS.items():
        add(f"{service}_Request", request or "uint8 structure_needs_at_least_one_member")
        add(f"{service}_Response", response)
        add(
            f"{service}_Event",
            f"service_msgs/msg/ServiceEventInfo info\n{service}_Request[<=1] request\n{service}_Response[<=1] response",
        )
        add(service, f"{service}_Request request_message\n{service}_Response response_message\n{service}_Event event_message")
    store.register(types)


class Level(IntEnum):
    """diagnostic_msgs/DiagnosticStatus levels."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


@dataclass(frozen=True, slots=True)
class Diagnostic:
    """One diagnostic_msgs/DiagnosticStatus: a level, a name, a message, the hardware, key/value pairs."""

    level: Level
    name: str
    message: str
    hardware_id: str = ""
    values: tuple[tuple[str, str], ...] = field(default=())


def excerpt(payload: bytes) -> str:
    """The first bytes of a binary payload in hex, as a person compares them with a dump."""
    head = payload[:24].hex(" ")
    return head + (" ..." if len(payload) > 24 else "")


@dataclass(frozen=True, slots=True)
class Frames:
    """The odometry's frames: ``odom`` -> the robot's root link, ``base_footprint`` (REP 105, as the URDF's root)."""

    odom: str = "odom"
    base: str = "base_footprint"


@dataclass(frozen=True, slots=True)
class Transform:
    """One geometry_msgs/TransformStamped: parent -> child, translation (m) and rotation (quaternion x, y, z, w)."""

    parent: str
    child: str
    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)


class RosCodec:
    """Encodes and decodes the adapter's ROS messages; one instance holds the type store."""

    def __init__(self) -> None:
        self.store = _store()
        t = self.store.types
        self._Time, self._Header = t["builtin_interfaces/msg/Time"], t["std_msgs/msg/Header"]
        self._Vector3, self._Quaternion = t["geometry_msgs/msg/Vector3"], t["geometry_msgs/msg/Quaternion"]
        self._Point, self._Pose = t["geometry_msgs/msg/Point"], t["geometry_msgs/msg/Pose"]
        self._PoseCov, self._Twist = t["geometry_msgs/msg/PoseWithCovariance"], t[TWIST]
        self._TwistCov, self._Odometry = t["geometry_msgs/msg/TwistWithCovariance"], t[ODOMETRY]
        self._Transform, self._TransformStamped = t["geometry_msgs/msg/Transform"], t["geometry_msgs/msg/TransformStamped"]
        self._TF, self._JointState = t[TF_MESSAGE], t[JOINT_STATE]
        self._DiagArray, self._DiagStatus = t[DIAGNOSTIC_ARRAY], t["diagnostic_msgs/msg/DiagnosticStatus"]
        self._KeyValue = t["diagnostic_msgs/msg/KeyValue"]

    def type_hash(self, ros_type: str) -> str:
        return str(self.store.hash_rihs01(ros_type))

    def _header(self, stamp: float, frame_id: str) -> Any:
        sec, nanosec = stamp_parts(stamp)
        return self._Header(stamp=self._Time(sec=sec, nanosec=nanosec), frame_id=frame_id)

    def _serialize(self, message: Any, ros_type: str) -> bytes:
        return bytes(self.store.serialize_cdr(message, ros_type))

    # --------------------------------------------------------------- out
    def odometry(self, pose: Pose, frames: Frames, pose_covariance: Any, twist_covariance: Any) -> bytes:
        """nav_msgs/Odometry: pose in ``odom``, twist in ``base_link``; covariances are 36-element arrays."""
        import numpy as np

        q = pose.orientation
        message = self._Odometry(
            header=self._header(pose.stamp, frames.odom),
            child_frame_id=frames.base,
            pose=self._PoseCov(
                pose=self._Pose(
                    position=self._Point(x=pose.x, y=pose.y, z=0.0),
                    orientation=self._Quaternion(x=q.x, y=q.y, z=q.z, w=q.w),
                ),
                covariance=np.asarray(pose_covariance, dtype=np.float64),
            ),
            twist=self._TwistCov(
                twist=self._Twist(linear=self._Vector3(x=pose.v, y=0.0, z=0.0), angular=self._Vector3(x=0.0, y=0.0, z=pose.w)),
                covariance=np.asarray(twist_covariance, dtype=np.float64),
            ),
        )
        return self._serialize(message, ODOMETRY)

    def transform(self, pose: Pose, frames: Frames) -> bytes:
        """tf2_msgs/TFMessage with the one transform odom -> base_link, stamped like the pose."""
        q = pose.orientation
        transform = self._TransformStamped(
            header=self._header(pose.stamp, frames.odom),
            child_frame_id=frames.base,
            transform=self._Transform(
                translation=self._Vector3(x=pose.x, y=pose.y, z=0.0),
                rotation=self._Quaternion(x=q.x, y=q.y, z=q.z, w=q.w),
            ),
        )
        return self._serialize(self._TF(transforms=[transform]), TF_MESSAGE)

    def transforms(self, stamp: float, transforms: Sequence[Transform]) -> bytes:
        """tf2_msgs/TFMessage of ``transforms``, all stamped ``stamp`` (Unix s)."""
        message = self._TF(
            transforms=[
                self._TransformStamped(
                    header=self._header(stamp, t.parent),
                    child_frame_id=t.child,
                    transform=self._Transform(
                        translation=self._Vector3(x=t.translation[0], y=t.translation[1], z=t.translation[2]),
                        rotation=self._Quaternion(x=t.rotation[0], y=t.rotation[1], z=t.rotation[2], w=t.rotation[3]),
                    ),
                )
                for t in transforms
            ]
        )
        return self._serialize(message, TF_MESSAGE)

    def string(self, text: str) -> bytes:
        """std_msgs/String (``/robot_description``)."""
        return self._serialize(self.store.types[STRING](data=text), STRING)

    def joint_state(self, stamp: float, names: list[str], positions: list[float], velocities: list[float]) -> bytes:
        import numpy as np

        message = self._JointState(
            header=self._header(stamp, ""),
            name=list(names),
            position=np.asarray(positions, dtype=np.float64),
            velocity=np.asarray(velocities, dtype=np.float64),
            effort=np.zeros(0, dtype=np.float64),
        )
        return self._serialize(message, JOINT_STATE)

    def diagnostics(self, stamp: float, statuses: Sequence[Diagnostic]) -> bytes:
        """diagnostic_msgs/DiagnosticArray of ``statuses``, stamped ``stamp`` (Unix s)."""
        message = self._DiagArray(
            header=self._header(stamp, ""),
            status=[
                self._DiagStatus(
                    level=int(d.level),
                    name=d.name,
                    message=d.message,
                    hardware_id=d.hardware_id,
                    values=[self._KeyValue(key=k, value=v) for k, v in d.values],
                )
                for d in statuses
            ],
        )
        return self._serialize(message, DIAGNOSTIC_ARRAY)

    def service_response(self, service: str, success: bool, message: str) -> bytes:
        """The ``<service>_Response`` (SetBool's and Trigger's are both ``bool success, string message``)."""
        response = self.store.types[f"{service}_Response"](success=success, message=message)
        return self._serialize(response, f"{service}_Response")

    # --------------------------------------------------------------- in
    def _decode(self, payload: bytes, ros_type: str) -> Any:
        short = ros_type.rsplit("/", 1)[-1]
        if len(payload) < 4:
            raise PayloadError(short, f"{len(payload)} bytes: a CDR message starts with a 4-byte encapsulation header", excerpt(payload))
        if payload[:2] not in CDR_HEADERS:
            raise PayloadError(
                short,
                f"encapsulation header {payload[:4].hex(' ')} is not plain CDR (expected 00 01 00 00, little-endian)",
                excerpt(payload),
            )
        try:
            return self.store.deserialize_cdr(payload, ros_type)
        except Exception as exc:  # rosbags raises SerdeError, struct.error, IndexError... for bad bytes
            raise PayloadError(short, f"not a valid CDR {ros_type} ({len(payload)} bytes): {exc}", excerpt(payload)) from None

    def twist(self, payload: bytes, stamped: bool = False) -> Twist:
        """geometry_msgs/Twist (or TwistStamped) CDR -> a blackmetal Twist; PayloadError if invalid or not finite."""
        return self._twist(payload, self._decode(payload, TWIST_STAMPED).twist if stamped else self._decode(payload, TWIST))

    def twist_stamped(self, payload: bytes) -> tuple[Twist, float]:
        """geometry_msgs/TwistStamped CDR -> the blackmetal Twist and the header's stamp (Unix s; 0.0 for a zero stamp)."""
        message = self._decode(payload, TWIST_STAMPED)
        stamp = message.header.stamp
        return self._twist(payload, message.twist), stamp.sec + stamp.nanosec * 1e-9

    def _twist(self, payload: bytes, twist: Any) -> Twist:
        values = {
            "linear.x": twist.linear.x,
            "linear.y": twist.linear.y,
            "linear.z": twist.linear.z,
            "angular.x": twist.angular.x,
            "angular.y": twist.angular.y,
            "angular.z": twist.angular.z,
        }
        bad = [name for name, value in values.items() if not math.isfinite(value)]
        if bad:
            raise PayloadError("Twist", f"{', '.join(bad)} must be finite numbers, got {[values[b] for b in bad]}", excerpt(payload))
        return Twist(
            linear=Vector3(x=twist.linear.x, y=twist.linear.y, z=twist.linear.z),
            angular=Vector3(x=twist.angular.x, y=twist.angular.y, z=twist.angular.z),
        )

    def estop(self, payload: bytes) -> EStop:
        """std_msgs/Bool CDR -> EStop(engaged=data)."""
        message = self._decode(payload, BOOL)
        return EStop(engaged=bool(message.data))

    def set_bool(self, payload: bytes) -> bool:
        """std_srvs/SetBool request CDR -> its ``data``."""
        return bool(self._decode(payload, f"{SET_BOOL}_Request").data)

    def trigger(self, payload: bytes) -> None:
        """std_srvs/Trigger request CDR (one placeholder byte): PayloadError unless it is one."""
        self._decode(payload, f"{TRIGGER}_Request")

    # --------------------------------------------------------------- for tests and tools playing the ROS side
    def encode_request(self, service: str, **fields: Any) -> bytes:
        """A ``<service>_Request`` as a ROS client sends it (Trigger: no fields)."""
        if service == TRIGGER:
            fields = {"structure_needs_at_least_one_member": 0}
        return self._serialize(self.store.types[f"{service}_Request"](**fields), f"{service}_Request")

    def encode_twist(self, linear_x: float, angular_z: float, stamp: float | None = None, frame_id: str = "") -> bytes:
        twist = self._Twist(linear=self._Vector3(x=linear_x, y=0.0, z=0.0), angular=self._Vector3(x=0.0, y=0.0, z=angular_z))
        if stamp is None:
            return self._serialize(twist, TWIST)
        stamped = self.store.types[TWIST_STAMPED](header=self._header(stamp, frame_id), twist=twist)
        return self._serialize(stamped, TWIST_STAMPED)

    def encode_bool(self, value: bool) -> bytes:
        return self._serialize(self.store.types[BOOL](data=value), BOOL)

    def decode(self, payload: bytes, ros_type: str) -> Any:
        """Any message of the store, as rosbags' dataclass (for tests and tools)."""
        return self._decode(payload, ros_type)
