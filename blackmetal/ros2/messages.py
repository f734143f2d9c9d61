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
import struct
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
PARAMETER_EVENT = "rcl_interfaces/msg/ParameterEvent"
LIST_PARAMETERS = "rcl_interfaces/srv/ListParameters"
GET_PARAMETERS = "rcl_interfaces/srv/GetParameters"
GET_PARAMETER_TYPES = "rcl_interfaces/srv/GetParameterTypes"
DESCRIBE_PARAMETERS = "rcl_interfaces/srv/DescribeParameters"
SET_PARAMETERS = "rcl_interfaces/srv/SetParameters"
SET_PARAMETERS_ATOMICALLY = "rcl_interfaces/srv/SetParametersAtomically"

#: The services' .srv text (request, response), as std_srvs and rcl_interfaces define them (comments left out: they
#: are not part of a type); an empty request gets rosidl's placeholder. rcl_interfaces' six parameter services are
#: the same text on humble, jazzy and rolling (ros2/rcl_interfaces, rcl_interfaces/srv/*.srv on each branch).
SERVICE_DEFINITIONS = {
    SET_BOOL: ("bool data", "bool success\nstring message"),
    TRIGGER: ("", "bool success\nstring message"),
    LIST_PARAMETERS: ("uint64 DEPTH_RECURSIVE=0\nstring[] prefixes\nuint64 depth", "rcl_interfaces/ListParametersResult result"),
    GET_PARAMETERS: ("string[] names", "rcl_interfaces/ParameterValue[] values"),
    GET_PARAMETER_TYPES: ("string[] names", "uint8[] types"),
    DESCRIBE_PARAMETERS: ("string[] names", "rcl_interfaces/ParameterDescriptor[] descriptors"),
    SET_PARAMETERS: ("rcl_interfaces/Parameter[] parameters", "rcl_interfaces/SetParametersResult[] results"),
    SET_PARAMETERS_ATOMICALLY: ("rcl_interfaces/Parameter[] parameters", "rcl_interfaces/SetParametersResult result"),
}


class ParameterType(IntEnum):
    """rcl_interfaces/msg/ParameterType."""

    NOT_SET = 0
    BOOL = 1
    INTEGER = 2
    DOUBLE = 3
    STRING = 4
    BYTE_ARRAY = 5
    BOOL_ARRAY = 6
    INTEGER_ARRAY = 7
    DOUBLE_ARRAY = 8
    STRING_ARRAY = 9


#: A ROS parameter value as the adapter reads one: a bool, an int, a float, a str, or (an array, unset) the type alone.
RosValue = bool | int | float | str | ParameterType


@dataclass(frozen=True, slots=True)
class Descriptor:
    """One rcl_interfaces/msg/ParameterDescriptor (a number's range goes in ``low``/``high``, step 0: any value)."""

    name: str
    type: ParameterType
    description: str = ""
    read_only: bool = False
    low: float | None = None
    high: float | None = None


#: CDR encapsulation headers ROS 2 writes: plain CDR, little- or big-endian.
CDR_HEADERS = (b"\x00\x01", b"\x00\x00")

#: A command's six doubles in little-endian CDR; and a TwistStamped's header stamp and frame_id length.
_SIX_DOUBLES = struct.Struct("<6d")
_STAMP_AND_LENGTH = struct.Struct("<iII")
_CDR_LE = b"\x00\x01\x00\x00"
_STAMP = struct.Struct("<iI")
_SEVEN_DOUBLES = struct.Struct("<7d")
_COVARIANCE = struct.Struct("<36d")


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
        self._odometry_frames: dict[Frames, bytes] = {}  # each node's frame names, as written in its /odom

    def type_hash(self, ros_type: str) -> str:
        return str(self.store.hash_rihs01(ros_type))

    def _header(self, stamp: float, frame_id: str) -> Any:
        sec, nanosec = stamp_parts(stamp)
        return self._Header(stamp=self._Time(sec=sec, nanosec=nanosec), frame_id=frame_id)

    def _serialize(self, message: Any, ros_type: str) -> bytes:
        return bytes(self.store.serialize_cdr(message, ros_type))

    # --------------------------------------------------------------- out
    def odometry(self, pose: Pose, frames: Frames, pose_covariance: Any, twist_covariance: Any) -> bytes:
        """nav_msgs/Odometry: pose in ``odom``, twist in ``base_link``; covariances are 36-element arrays.

        Written straight into little-endian CDR (every /odom of a fleet goes through here: 7 us against rosbags'
        18); :meth:`odometry_reference` is rosbags' writing of the same message, and a test holds them equal.
        """
        middle = self._odometry_frames.get(frames)
        if middle is None:
            middle = self._odometry_frames[frames] = _odometry_frames(frames)
        sec, nanosec = stamp_parts(pose.stamp)
        q = pose.orientation
        return b"".join(
            (
                _CDR_LE,
                _STAMP.pack(sec, nanosec),
                middle,
                _SEVEN_DOUBLES.pack(pose.x, pose.y, 0.0, q.x, q.y, q.z, q.w),
                _COVARIANCE.pack(*pose_covariance),
                _SIX_DOUBLES.pack(pose.v, 0.0, 0.0, 0.0, 0.0, pose.w),
                _COVARIANCE.pack(*twist_covariance),
            )
        )

    def odometry_reference(self, pose: Pose, frames: Frames, pose_covariance: Any, twist_covariance: Any) -> bytes:
        """:meth:`odometry` written by rosbags, field by field (the reference the fast writing is tested against)."""
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

    # --------------------------------------------------------------- parameters (rcl_interfaces)
    def _value(self, value: RosValue | None) -> Any:
        """A ParameterValue of a bool, int, float or str (None: PARAMETER_NOT_SET)."""
        import numpy as np

        kinds: dict[type, tuple[ParameterType, str]] = {
            bool: (ParameterType.BOOL, "bool_value"),
            int: (ParameterType.INTEGER, "integer_value"),
            float: (ParameterType.DOUBLE, "double_value"),
            str: (ParameterType.STRING, "string_value"),
        }
        fields: dict[str, Any] = {
            "type": int(ParameterType.NOT_SET),
            "bool_value": False,
            "integer_value": 0,
            "double_value": 0.0,
            "string_value": "",
            "byte_array_value": np.zeros(0, dtype=np.uint8),
            "bool_array_value": np.zeros(0, dtype=np.bool_),
            "integer_array_value": np.zeros(0, dtype=np.int64),
            "double_array_value": np.zeros(0, dtype=np.float64),
            "string_array_value": [],
        }
        if value is not None and not isinstance(value, ParameterType):
            kind, name = kinds[type(value)]
            fields["type"], fields[name] = int(kind), value
        return self.store.types["rcl_interfaces/msg/ParameterValue"](**fields)

    def _response(self, service: str, **fields: Any) -> bytes:
        return self._serialize(self.store.types[f"{service}_Response"](**fields), f"{service}_Response")

    def list_parameters_response(self, names: Sequence[str], prefixes: Sequence[str]) -> bytes:
        result = self.store.types["rcl_interfaces/msg/ListParametersResult"](names=list(names), prefixes=list(prefixes))
        return self._response(LIST_PARAMETERS, result=result)

    def get_parameters_response(self, values: Sequence[RosValue | None]) -> bytes:
        return self._response(GET_PARAMETERS, values=[self._value(v) for v in values])

    def get_parameter_types_response(self, types: Sequence[ParameterType]) -> bytes:
        import numpy as np

        return self._response(GET_PARAMETER_TYPES, types=np.asarray([int(t) for t in types], dtype=np.uint8))

    def describe_parameters_response(self, descriptors: Sequence[Descriptor]) -> bytes:
        t = self.store.types
        out = []
        for d in descriptors:
            floats, integers = [], []
            if d.low is not None and d.high is not None and d.type is ParameterType.DOUBLE:
                floats = [t["rcl_interfaces/msg/FloatingPointRange"](from_value=d.low, to_value=d.high, step=0.0)]
            elif d.low is not None and d.high is not None and d.type is ParameterType.INTEGER:
                integers = [t["rcl_interfaces/msg/IntegerRange"](from_value=int(d.low), to_value=int(d.high), step=0)]
            out.append(
                t["rcl_interfaces/msg/ParameterDescriptor"](
                    name=d.name,
                    type=int(d.type),
                    description=d.description,
                    additional_constraints="",
                    read_only=d.read_only,
                    dynamic_typing=False,
                    floating_point_range=floats,
                    integer_range=integers,
                )
            )
        return self._response(DESCRIBE_PARAMETERS, descriptors=out)

    def _result(self, successful: bool, reason: str) -> Any:
        return self.store.types["rcl_interfaces/msg/SetParametersResult"](successful=successful, reason=reason)

    def set_parameters_response(self, results: Sequence[tuple[bool, str]]) -> bytes:
        return self._response(SET_PARAMETERS, results=[self._result(ok, reason) for ok, reason in results])

    def set_parameters_atomically_response(self, successful: bool, reason: str) -> bytes:
        return self._response(SET_PARAMETERS_ATOMICALLY, result=self._result(successful, reason))

    def parameter_event(
        self, stamp: float, node: str, new: Sequence[tuple[str, RosValue]], changed: Sequence[tuple[str, RosValue]]
    ) -> bytes:
        """rcl_interfaces/msg/ParameterEvent (``/parameter_events``) from the node ``node`` (fully qualified)."""
        sec, nanosec = stamp_parts(stamp)
        parameter = self.store.types["rcl_interfaces/msg/Parameter"]
        message = self.store.types[PARAMETER_EVENT](
            stamp=self._Time(sec=sec, nanosec=nanosec),
            node=node,
            new_parameters=[parameter(name=name, value=self._value(value)) for name, value in new],
            changed_parameters=[parameter(name=name, value=self._value(value)) for name, value in changed],
            deleted_parameters=[],
        )
        return self._serialize(message, PARAMETER_EVENT)

    def names_request(self, service: str, payload: bytes) -> list[str]:
        """The ``names`` of a GetParameters, GetParameterTypes or DescribeParameters request."""
        return [str(name) for name in self._decode(payload, f"{service}_Request").names]

    def list_parameters_request(self, payload: bytes) -> tuple[list[str], int]:
        """(prefixes, depth) of a ListParameters request."""
        request = self._decode(payload, f"{LIST_PARAMETERS}_Request")
        return [str(p) for p in request.prefixes], int(request.depth)

    def set_parameters_request(self, service: str, payload: bytes) -> list[tuple[str, RosValue]]:
        """The (name, value) pairs of a SetParameters(Atomically) request; a value that is not a bool, an integer, a
        double or a string comes as its :class:`ParameterType` alone (the caller refuses it)."""
        out: list[tuple[str, RosValue]] = []
        for parameter in self._decode(payload, f"{service}_Request").parameters:
            v = parameter.value
            try:
                kind = ParameterType(v.type)
            except ValueError:
                raise PayloadError(
                    "Parameter", f"{parameter.name}: parameter type {v.type} is not one of rcl_interfaces' 0..9", ""
                ) from None
            scalars: dict[ParameterType, RosValue] = {
                ParameterType.BOOL: bool(v.bool_value),
                ParameterType.INTEGER: int(v.integer_value),
                ParameterType.DOUBLE: float(v.double_value),
                ParameterType.STRING: str(v.string_value),
            }
            out.append((str(parameter.name), scalars.get(kind, kind)))
        return out

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
        if stamped:
            return self.twist_stamped(payload)[0]
        if len(payload) == 52 and payload[:2] == b"\x00\x01":  # rmw_zenoh's own: little-endian, six doubles
            return self._finite_twist(payload, _SIX_DOUBLES.unpack_from(payload, 4))
        return self._twist(payload, self._decode(payload, TWIST))

    def twist_stamped(self, payload: bytes) -> tuple[Twist, float]:
        """geometry_msgs/TwistStamped CDR -> the blackmetal Twist and the header's stamp (Unix s; 0.0 for a zero stamp)."""
        fast = _twist_stamped_le(payload)
        if fast is not None:
            sec, nanosec, values = fast
            return self._finite_twist(payload, values), sec + nanosec * 1e-9
        message = self._decode(payload, TWIST_STAMPED)
        stamp = message.header.stamp
        return self._twist(payload, message.twist), stamp.sec + stamp.nanosec * 1e-9

    def _finite_twist(self, payload: bytes, values: tuple[float, ...]) -> Twist:
        """A command read straight from the bytes (a ROS command is taken on Zenoh's thread: 2 us against rosbags' 8)."""
        if not all(map(math.isfinite, values)):  # rosbags' reading says which are not
            stamped = len(payload) != 52
            return self._twist(payload, self._decode(payload, TWIST_STAMPED).twist if stamped else self._decode(payload, TWIST))
        lx, ly, lz, ax, ay, az = values
        return Twist(linear=Vector3(x=lx, y=ly, z=lz), angular=Vector3(x=ax, y=ay, z=az))

    def _twist(self, payload: bytes, twist: Any) -> Twist:  # rosbags' message: the reference path, and its errors
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
        """A ``<service>_Request`` as a ROS client sends it (Trigger: no fields; SetParameters: ``parameters`` as
        (name, value) pairs)."""
        if service == TRIGGER:
            fields = {"structure_needs_at_least_one_member": 0}
        if "parameters" in fields:
            parameter = self.store.types["rcl_interfaces/msg/Parameter"]
            fields["parameters"] = [parameter(name=name, value=self._value(value)) for name, value in fields["parameters"]]
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


def _twist_stamped_le(payload: bytes) -> tuple[int, int, tuple[float, ...]] | None:
    """A little-endian geometry_msgs/TwistStamped read straight from its bytes: (sec, nanosec, the six doubles).

    None for anything else (big-endian, a frame_id that is not NUL-terminated
    UTF-8, a length that does not add up): rosbags reads those and says
    what is wrong. The layout, after the 4-byte encapsulation header: int32
    sec, uint32 nanosec, uint32 length of frame_id with its NUL, its bytes,
    padding to 8 (counted from after the header), six doubles.
    """
    if len(payload) < 68 or payload[:2] != b"\x00\x01":
        return None
    sec, nanosec, length = _STAMP_AND_LENGTH.unpack_from(payload, 4)
    end = 16 + length
    start = 4 + (end - 4 + 7) // 8 * 8
    if length == 0 or len(payload) != start + 48 or payload[end - 1] != 0:
        return None
    try:
        payload[16 : end - 1].decode()
    except UnicodeDecodeError:
        return None
    return sec, nanosec, _SIX_DOUBLES.unpack_from(payload, start)


def _cdr_string(text: str, offset: int) -> tuple[bytes, int]:
    """A CDR string at ``offset`` (counted after the encapsulation header): its padding to 4, length with the NUL, bytes."""
    data = text.encode() + b"\x00"
    pad = -offset % 4
    return b"\x00" * pad + struct.pack("<I", len(data)) + data, offset + pad + 4 + len(data)


def _odometry_frames(frames: Frames) -> bytes:
    """nav_msgs/Odometry's bytes between the stamp and the first double: frame_id, child_frame_id, padding to 8."""
    header, offset = _cdr_string(frames.odom, 8)
    child, offset = _cdr_string(frames.base, offset)
    return header + child + b"\x00" * (-offset % 8)
