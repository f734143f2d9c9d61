"""ROS 2 messages as CDR bytes, both ways, with the type store of :mod:`.ros_types`.

The adapter's whole contact with ROS messages: blackmetal messages in, CDR
bytes out (``/odom``, ``/tf``, ``/joint_states``, ``/diagnostics``, service
responses), and CDR bytes in, blackmetal messages out (``/cmd_vel``,
``/estop``, service requests). Decoding is strict: a payload that is not
exactly one valid message of the expected type, or that carries a
non-finite number, is a :class:`PayloadError` saying why. The hot paths
(``/odom`` out, commands in) are written by hand in :mod:`.cdr`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from blackmetal.runtime.diagnostics import Status
from blackmetal.schemas import EStop, Param, PayloadError, Pose, Twist, Vector3, stamp_parts

from . import cdr
from . import ros_types as ros
from .ros_types import Frames, ParameterType, RosValue, Transform, excerpt, type_store


class RosCodec:
    """Encodes and decodes the adapter's ROS messages; one instance holds the type store."""

    def __init__(self) -> None:
        self.store = type_store()
        t = self.store.types
        self._Time, self._Header = t["builtin_interfaces/msg/Time"], t["std_msgs/msg/Header"]
        self._Vector3, self._Quaternion = t["geometry_msgs/msg/Vector3"], t["geometry_msgs/msg/Quaternion"]
        self._Twist = t[ros.TWIST]
        self._Transform, self._TransformStamped = t["geometry_msgs/msg/Transform"], t["geometry_msgs/msg/TransformStamped"]
        self._DiagStatus, self._KeyValue = t["diagnostic_msgs/msg/DiagnosticStatus"], t["diagnostic_msgs/msg/KeyValue"]
        self._odometry_frames: dict[Frames, bytes] = {}  # each node's frame names, as written in its /odom

    def type_hash(self, ros_type: str) -> str:
        return str(self.store.hash_rihs01(ros_type))

    def _header(self, stamp: float, frame_id: str) -> Any:
        sec, nanosec = stamp_parts(stamp)
        return self._Header(stamp=self._Time(sec=sec, nanosec=nanosec), frame_id=frame_id)

    def _write(self, ros_type: str, **fields: Any) -> bytes:
        """A ``ros_type`` message of ``fields``, in CDR."""
        return bytes(self.store.serialize_cdr(self.store.types[ros_type](**fields), ros_type))

    # --------------------------------------------------------------- out
    def odometry(self, pose: Pose, frames: Frames, pose_covariance: Any, twist_covariance: Any) -> bytes:
        """nav_msgs/Odometry: pose in ``odom``, twist in ``base_link``; covariances are 36-element arrays.

        Written by :mod:`.cdr` (every /odom of a fleet goes through here); a test holds it equal to rosbags' writing
        of the same message.
        """
        middle = self._odometry_frames.get(frames)
        if middle is None:
            middle = self._odometry_frames[frames] = cdr.odometry_frames(frames)
        return cdr.odometry(pose, middle, pose_covariance, twist_covariance)

    def transform(self, pose: Pose, frames: Frames) -> bytes:
        """tf2_msgs/TFMessage with the one transform odom -> base_link, stamped like the pose."""
        q = pose.orientation
        return self.transforms(pose.stamp, [Transform(frames.odom, frames.base, (pose.x, pose.y, 0.0), (q.x, q.y, q.z, q.w))])

    def transforms(self, stamp: float, transforms: Sequence[Transform]) -> bytes:
        """tf2_msgs/TFMessage of ``transforms``, all stamped ``stamp`` (Unix s)."""
        return self._write(
            ros.TF_MESSAGE,
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
            ],
        )

    def string(self, text: str) -> bytes:
        """std_msgs/String (``/robot_description``)."""
        return self._write(ros.STRING, data=text)

    def joint_state(self, stamp: float, names: list[str], positions: list[float], velocities: list[float]) -> bytes:
        import numpy as np

        return self._write(
            ros.JOINT_STATE,
            header=self._header(stamp, ""),
            name=list(names),
            position=np.asarray(positions, dtype=np.float64),
            velocity=np.asarray(velocities, dtype=np.float64),
            effort=np.zeros(0, dtype=np.float64),
        )

    def diagnostics(self, stamp: float, statuses: Sequence[Status]) -> bytes:
        """diagnostic_msgs/DiagnosticArray of ``statuses``, stamped ``stamp`` (Unix s)."""
        return self._write(
            ros.DIAGNOSTIC_ARRAY,
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

    def service_response(self, service: str, success: bool, message: str) -> bytes:
        """The ``<service>_Response`` (SetBool's and Trigger's are both ``bool success, string message``)."""
        return self._response(service, success=success, message=message)

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
        return self._write(f"{service}_Response", **fields)

    def list_parameters_response(self, names: Sequence[str], prefixes: Sequence[str]) -> bytes:
        result = self.store.types["rcl_interfaces/msg/ListParametersResult"](names=list(names), prefixes=list(prefixes))
        return self._response(ros.LIST_PARAMETERS, result=result)

    def get_parameters_response(self, values: Sequence[RosValue | None]) -> bytes:
        return self._response(ros.GET_PARAMETERS, values=[self._value(v) for v in values])

    def get_parameter_types_response(self, types: Sequence[ParameterType]) -> bytes:
        import numpy as np

        return self._response(ros.GET_PARAMETER_TYPES, types=np.asarray([int(t) for t in types], dtype=np.uint8))

    def describe_parameters_response(self, params: Sequence[Param]) -> bytes:
        """A ParameterDescriptor of each parameter of the gateway's table (a number's range from ``min``/``max``, step
        0: any value; a kind rcl_interfaces does not have: NOT_SET)."""
        t = self.store.types
        out = []
        for p in params:
            kind, floats, integers = ParameterType.of(p.type), [], []
            if p.min is not None and p.max is not None and kind is ParameterType.DOUBLE:
                floats = [t["rcl_interfaces/msg/FloatingPointRange"](from_value=p.min, to_value=p.max, step=0.0)]
            elif p.min is not None and p.max is not None and kind is ParameterType.INTEGER:
                integers = [t["rcl_interfaces/msg/IntegerRange"](from_value=int(p.min), to_value=int(p.max), step=0)]
            out.append(
                t["rcl_interfaces/msg/ParameterDescriptor"](
                    name=p.name,
                    type=int(kind),
                    description=p.description,
                    additional_constraints="",
                    read_only=p.read_only,
                    dynamic_typing=False,
                    floating_point_range=floats,
                    integer_range=integers,
                )
            )
        return self._response(ros.DESCRIBE_PARAMETERS, descriptors=out)

    def _result(self, successful: bool, reason: str) -> Any:
        return self.store.types["rcl_interfaces/msg/SetParametersResult"](successful=successful, reason=reason)

    def set_parameters_response(self, results: Sequence[tuple[bool, str]]) -> bytes:
        return self._response(ros.SET_PARAMETERS, results=[self._result(ok, reason) for ok, reason in results])

    def set_parameters_atomically_response(self, successful: bool, reason: str) -> bytes:
        return self._response(ros.SET_PARAMETERS_ATOMICALLY, result=self._result(successful, reason))

    def parameter_event(
        self, stamp: float, node: str, new: Sequence[tuple[str, RosValue]], changed: Sequence[tuple[str, RosValue]]
    ) -> bytes:
        """rcl_interfaces/msg/ParameterEvent (``/parameter_events``) from the node ``node`` (fully qualified)."""
        sec, nanosec = stamp_parts(stamp)
        return self._write(
            ros.PARAMETER_EVENT,
            stamp=self._Time(sec=sec, nanosec=nanosec),
            node=node,
            new_parameters=self._parameters(new),
            changed_parameters=self._parameters(changed),
            deleted_parameters=[],
        )

    def _parameters(self, pairs: Sequence[tuple[str, RosValue]]) -> list[Any]:
        """rcl_interfaces/msg/Parameter of each (name, value)."""
        parameter = self.store.types["rcl_interfaces/msg/Parameter"]
        return [parameter(name=name, value=self._value(value)) for name, value in pairs]

    def names_request(self, service: str, payload: bytes) -> list[str]:
        """The ``names`` of a GetParameters, GetParameterTypes or DescribeParameters request."""
        return [str(name) for name in self.decode(payload, f"{service}_Request").names]

    def list_parameters_request(self, payload: bytes) -> tuple[list[str], int]:
        """(prefixes, depth) of a ListParameters request."""
        request = self.decode(payload, f"{ros.LIST_PARAMETERS}_Request")
        return [str(p) for p in request.prefixes], int(request.depth)

    def set_parameters_request(self, service: str, payload: bytes) -> list[tuple[str, RosValue]]:
        """The (name, value) pairs of a SetParameters(Atomically) request; a value that is not a bool, an integer, a
        double or a string comes as its :class:`ParameterType` alone (the caller refuses it)."""
        out: list[tuple[str, RosValue]] = []
        for parameter in self.decode(payload, f"{service}_Request").parameters:
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
    def decode(self, payload: bytes, ros_type: str) -> Any:
        """One message of ``ros_type``, as rosbags' dataclass; PayloadError if it is not exactly one."""
        short = ros_type.rsplit("/", 1)[-1]
        if len(payload) < 4:
            raise PayloadError(short, f"{len(payload)} bytes: a CDR message starts with a 4-byte encapsulation header", excerpt(payload))
        if payload[:2] not in ros.CDR_HEADERS:
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
        fast = cdr.twist_le(payload)  # rmw_zenoh's own: little-endian, six doubles
        if fast is not None:
            return self._finite_twist(payload, fast)
        return self._twist(payload, self.decode(payload, ros.TWIST))

    def twist_stamped(self, payload: bytes) -> tuple[Twist, float]:
        """geometry_msgs/TwistStamped CDR -> the blackmetal Twist and the header's stamp (Unix s; 0.0 for a zero stamp)."""
        fast = cdr.twist_stamped_le(payload)
        if fast is not None:
            sec, nanosec, values = fast
            return self._finite_twist(payload, values), sec + nanosec * 1e-9
        message = self.decode(payload, ros.TWIST_STAMPED)
        stamp = message.header.stamp
        return self._twist(payload, message.twist), stamp.sec + stamp.nanosec * 1e-9

    def _finite_twist(self, payload: bytes, values: tuple[float, ...]) -> Twist:
        """A command read straight from the bytes by :mod:`.cdr` (a ROS command is taken on Zenoh's thread)."""
        if not all(map(math.isfinite, values)):  # rosbags' reading says which are not
            stamped = len(payload) != cdr.TWIST_LE_SIZE
            return self._twist(payload, self.decode(payload, ros.TWIST_STAMPED).twist if stamped else self.decode(payload, ros.TWIST))
        return _as_twist(values)

    def _twist(self, payload: bytes, twist: Any) -> Twist:  # rosbags' message: the reference path, and its errors
        values = {f"{part}.{axis}": getattr(getattr(twist, part), axis) for part in ("linear", "angular") for axis in "xyz"}
        bad = [name for name, value in values.items() if not math.isfinite(value)]
        if bad:
            raise PayloadError("Twist", f"{', '.join(bad)} must be finite numbers, got {[values[b] for b in bad]}", excerpt(payload))
        return _as_twist(tuple(values.values()))

    def estop(self, payload: bytes) -> EStop:
        """std_msgs/Bool CDR -> EStop(engaged=data)."""
        message = self.decode(payload, ros.BOOL)
        return EStop(engaged=bool(message.data))

    def set_bool(self, payload: bytes) -> bool:
        """std_srvs/SetBool request CDR -> its ``data``."""
        return bool(self.decode(payload, f"{ros.SET_BOOL}_Request").data)

    def trigger(self, payload: bytes) -> None:
        """std_srvs/Trigger request CDR (one placeholder byte): PayloadError unless it is one."""
        self.decode(payload, f"{ros.TRIGGER}_Request")

    # --------------------------------------------------------------- for tests and tools playing the ROS side
    def encode_request(self, service: str, **fields: Any) -> bytes:
        """A ``<service>_Request`` as a ROS client sends it (Trigger: no fields; SetParameters: ``parameters`` as
        (name, value) pairs)."""
        if service == ros.TRIGGER:
            fields = {"structure_needs_at_least_one_member": 0}
        if "parameters" in fields:
            fields["parameters"] = self._parameters(fields["parameters"])
        return self._write(f"{service}_Request", **fields)

    def encode_twist(self, linear_x: float, angular_z: float, stamp: float | None = None, frame_id: str = "") -> bytes:
        linear, angular = self._Vector3(x=linear_x, y=0.0, z=0.0), self._Vector3(x=0.0, y=0.0, z=angular_z)
        if stamp is None:
            return self._write(ros.TWIST, linear=linear, angular=angular)
        return self._write(ros.TWIST_STAMPED, header=self._header(stamp, frame_id), twist=self._Twist(linear=linear, angular=angular))

    def encode_bool(self, value: bool) -> bytes:
        return self._write(ros.BOOL, data=value)


def _as_twist(values: tuple[float, ...]) -> Twist:
    """linear x, y, z and angular x, y, z as a blackmetal Twist."""
    lx, ly, lz, ax, ay, az = values
    return Twist(linear=Vector3(x=lx, y=ly, z=lz), angular=Vector3(x=ax, y=ay, z=az))
