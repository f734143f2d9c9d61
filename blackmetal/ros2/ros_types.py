"""The ROS types the node speaks: their names, rosbags' store of them, and the plain values the codec takes.

Type hashes (``RIHS01_...``) are computed by rosbags, never copied by hand. rosbags' store has no ``std_srvs``: the
services are registered here from their ``.srv`` text with the service-level types rosidl hashes, and ``char``
fields are read as ``uint8``, as rosidl maps them (so every service hash matches ROS 2's).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Any

from blackmetal.schemas import require_extra

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

    @classmethod
    def of(cls, kind: str) -> ParameterType:
        """The gateway's kind of value (``bool``, ``integer``, ``double``, ``string``) as rcl_interfaces names it."""
        return {"bool": cls.BOOL, "integer": cls.INTEGER, "double": cls.DOUBLE, "string": cls.STRING}.get(kind, cls.NOT_SET)


#: A ROS parameter value as the adapter reads one: a bool, an int, a float, a str, or (an array, unset) the type alone.
RosValue = bool | int | float | str | ParameterType


#: CDR encapsulation headers ROS 2 writes: plain CDR, little- or big-endian.
CDR_HEADERS = (b"\x00\x01", b"\x00\x00")


def type_store() -> Any:
    """A fresh rosbags store of the Jazzy types, read as rosidl reads them, with the services below registered."""
    require_extra("blackmetal ros2", "ros2", "rosbags")
    require_extra("blackmetal ros2", "ros2", "xxhash")
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)  # a fresh store: what is changed below stays in it
    for name, (consts, fields) in list(store.fielddefs.items()):
        store.fielddefs[name] = (consts, [(fname, _as_rosidl(desc)) for fname, desc in fields])
    # each service as rosidl describes one: <srv>_Request, _Response, _Event and the service type itself
    types: dict[str, Any] = {}

    def add(typename: str, text: str) -> None:
        for name, (consts, fields) in get_types_from_msg(text, typename).items():
            types[_service_name(name)] = (consts, [(fname, _as_rosidl(desc)) for fname, desc in fields])

    for service, (request, response) in SERVICE_DEFINITIONS.items():
        add(f"{service}_Request", request or "uint8 structure_needs_at_least_one_member")
        add(f"{service}_Response", response)
        add(
            f"{service}_Event",
            f"service_msgs/msg/ServiceEventInfo info\n{service}_Request[<=1] request\n{service}_Response[<=1] response",
        )
        add(service, f"{service}_Request request_message\n{service}_Response response_message\n{service}_Event event_message")
    store.register(types)
    return store


def _service_name(typename: str) -> str:
    """rosbags reads "pkg/srv/Name" as "pkg/srv/msg/Name"."""
    return typename.replace("/srv/msg/", "/srv/")


def _as_rosidl(desc: Any) -> Any:
    """A field's type as rosidl maps it: ``char`` as ``uint8`` (the same one byte in CDR; rosbags' ``char`` changes
    the hashes), a service's own types by their service name."""
    from rosbags.typesys.base import Nodetype

    kind, rest = desc
    if kind == Nodetype.BASE and rest[0] == "char":
        return (kind, ("uint8", rest[1]))
    if kind == Nodetype.NAME:
        return (kind, _service_name(rest))
    if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        return (kind, (_as_rosidl(rest[0]), rest[1]))
    return desc


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
