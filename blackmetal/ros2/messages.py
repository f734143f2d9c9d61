"""ROS 2 messages as CDR bytes, both ways, with the type store of :mod:`.ros_types`.

Decoding is strict: a payload that is not exactly one valid message of the expected type, or that carries a
non-finite number, is a :class:`PayloadError` saying why. The hot paths (``/odom`` out, commands in) are in :mod:`.cdr`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from blackmetal.runtime.diagnostics import Status
from blackmetal.schemas import Param, PayloadError, Pose, Twist, Vector3, stamp_parts

from . import cdr
from . import ros_types as ros
from .parameters import list_names, ros_value
from .ros_types import Frames, ParameterType, RosValue, Transform, excerpt, type_store


class RosCodec:
    """Encodes and decodes the adapter's ROS messages; one instance holds the type store."""

    def __init__(self) -> None:
        self.store = type_store()
        self._odometry_frames: dict[Frames, bytes] = {}  # each node's frame names, as written in its /odom

    def type_hash(self, ros_type: str) -> str:
        return str(self.store.hash_rihs01(ros_type))

    def message(self, ros_type: str, **fields: Any) -> Any:
        """A ``ros_type`` message of ``fields``, as rosbags' dataclass (``geometry_msgs/msg/Vector3``, ...)."""
        return self.store.types[ros_type](**fields)

    def encode(self, ros_type: str, **fields: Any) -> bytes:
        return bytes(self.store.serialize_cdr(self.message(ros_type, **fields), ros_type))

    def time(self, stamp: float) -> Any:
        sec, nanosec = stamp_parts(stamp)
        return self.message("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)

    def header(self, stamp: float, frame_id: str) -> Any:
        return self.message("std_msgs/msg/Header", stamp=self.time(stamp), frame_id=frame_id)

    def vector3(self, x: float, y: float, z: float) -> Any:
        return self.message("geometry_msgs/msg/Vector3", x=x, y=y, z=z)

    def odometry(self, pose: Pose, frames: Frames, pose_covariance: Any, twist_covariance: Any) -> bytes:
        """nav_msgs/Odometry, written by :mod:`.cdr` (every /odom of a fleet goes through here); covariances: 36 values."""
        middle = self._odometry_frames.get(frames)
        if middle is None:
            middle = self._odometry_frames[frames] = cdr.odometry_frames(frames)
        return cdr.odometry(pose, middle, pose_covariance, twist_covariance)

    def transform(self, pose: Pose, frames: Frames) -> bytes:
        """tf2_msgs/TFMessage with the one transform odom -> base_link, stamped like the pose."""
        q = pose.orientation
        return self.transforms(pose.stamp, [Transform(frames.odom, frames.base, (pose.x, pose.y, 0.0), (q.x, q.y, q.z, q.w))])

    def transforms(self, stamp: float, transforms: Sequence[Transform]) -> bytes:
        """tf2_msgs/TFMessage of ``transforms``, stamped ``stamp``; the classes looked up once (every /tf of a fleet)."""
        types = self.store.types
        stamped, transform = types["geometry_msgs/msg/TransformStamped"], types["geometry_msgs/msg/Transform"]
        vector3, quaternion = types["geometry_msgs/msg/Vector3"], types["geometry_msgs/msg/Quaternion"]
        message = types[ros.TF_MESSAGE](
            transforms=[
                stamped(
                    header=self.header(stamp, t.parent),
                    child_frame_id=t.child,
                    transform=transform(translation=vector3(*t.translation), rotation=quaternion(*t.rotation)),
                )
                for t in transforms
            ]
        )
        return bytes(self.store.serialize_cdr(message, ros.TF_MESSAGE))

    def joint_state(self, stamp: float, names: list[str], positions: list[float], velocities: list[float]) -> bytes:
        import numpy as np

        return self.encode(
            ros.JOINT_STATE,
            header=self.header(stamp, ""),
            name=list(names),
            position=np.asarray(positions, dtype=np.float64),
            velocity=np.asarray(velocities, dtype=np.float64),
            effort=np.zeros(0, dtype=np.float64),
        )

    def diagnostics(self, stamp: float, statuses: Sequence[Status]) -> bytes:
        return self.encode(
            ros.DIAGNOSTIC_ARRAY,
            header=self.header(stamp, ""),
            status=[
                self.message(
                    "diagnostic_msgs/msg/DiagnosticStatus",
                    level=int(d.level),
                    name=d.name,
                    message=d.message,
                    hardware_id=d.hardware_id,
                    values=[self.message("diagnostic_msgs/msg/KeyValue", key=k, value=v) for k, v in d.values],
                )
                for d in statuses
            ],
        )

    def response(self, service: str, **fields: Any) -> bytes:
        """The ``<service>_Response`` of ``fields`` (SetBool's and Trigger's are both ``bool success, string message``)."""
        return self.encode(f"{service}_Response", **fields)

    def _value(self, value: RosValue | None) -> Any:
        """A ParameterValue of a bool, int, float or str (None: PARAMETER_NOT_SET); every ``<kind>_value`` is written."""
        import numpy as np

        empty: dict[ParameterType, Any] = {
            ParameterType.BOOL: False,
            ParameterType.INTEGER: 0,
            ParameterType.DOUBLE: 0.0,
            ParameterType.STRING: "",
            ParameterType.BYTE_ARRAY: np.zeros(0, dtype=np.uint8),
            ParameterType.BOOL_ARRAY: np.zeros(0, dtype=np.bool_),
            ParameterType.INTEGER_ARRAY: np.zeros(0, dtype=np.int64),
            ParameterType.DOUBLE_ARRAY: np.zeros(0, dtype=np.float64),
            ParameterType.STRING_ARRAY: [],
        }
        fields = {f"{kind.name.lower()}_value": zero for kind, zero in empty.items()}
        kind = ParameterType.NOT_SET
        if value is not None and not isinstance(value, ParameterType):
            kind = {bool: ParameterType.BOOL, int: ParameterType.INTEGER, float: ParameterType.DOUBLE, str: ParameterType.STRING}[
                type(value)
            ]
            fields[f"{kind.name.lower()}_value"] = value
        return self.message("rcl_interfaces/msg/ParameterValue", type=int(kind), **fields)

    def parameter_response(self, service: str, payload: bytes, table: dict[str, Param]) -> bytes:
        """The response of a parameter read service (``service``: its type), answered from the gateway's ``table``; an
        unknown name gets no value, NOT_SET, a descriptor of no kind (the .srv asks for one per name)."""
        import numpy as np

        request = self.request(service, payload)
        if service == ros.LIST_PARAMETERS:
            names, prefixes = list_names(list(table), [str(p) for p in request.prefixes], int(request.depth))
            return self.response(service, result=self.message("rcl_interfaces/msg/ListParametersResult", names=names, prefixes=prefixes))
        asked = [str(name) for name in request.names]
        if service == ros.GET_PARAMETERS:
            return self.response(service, values=[self._value(ros_value(table[n]) if n in table else None) for n in asked])
        if service == ros.GET_PARAMETER_TYPES:
            types = [ParameterType.of(table[n].type) if n in table else ParameterType.NOT_SET for n in asked]
            return self.response(service, types=np.asarray(types, dtype=np.uint8))
        return self.response(service, descriptors=[self._descriptor(table.get(n) or Param(name=n, type="", value="")) for n in asked])

    def _descriptor(self, p: Param) -> Any:
        kind, floats, integers = ParameterType.of(p.type), [], []
        if p.min is not None and p.max is not None and kind is ParameterType.DOUBLE:
            floats = [self.message("rcl_interfaces/msg/FloatingPointRange", from_value=p.min, to_value=p.max, step=0.0)]
        elif p.min is not None and p.max is not None and kind is ParameterType.INTEGER:
            integers = [self.message("rcl_interfaces/msg/IntegerRange", from_value=int(p.min), to_value=int(p.max), step=0)]
        return self.message(
            "rcl_interfaces/msg/ParameterDescriptor",
            name=p.name,
            type=int(kind),
            description=p.description,
            additional_constraints="",
            read_only=p.read_only,
            dynamic_typing=False,
            floating_point_range=floats,
            integer_range=integers,
        )

    def set_parameters_response(self, service: str, results: Sequence[tuple[bool, str]]) -> bytes:
        out = [self.message("rcl_interfaces/msg/SetParametersResult", successful=ok, reason=reason) for ok, reason in results]
        return self.response(service, results=out) if service == ros.SET_PARAMETERS else self.response(service, result=out[0])

    def parameter_event(
        self, stamp: float, node: str, new: Sequence[tuple[str, RosValue]], changed: Sequence[tuple[str, RosValue]]
    ) -> bytes:
        """rcl_interfaces/msg/ParameterEvent (``/parameter_events``) from the node ``node`` (fully qualified)."""
        return self.encode(
            ros.PARAMETER_EVENT,
            stamp=self.time(stamp),
            node=node,
            new_parameters=self.parameters(new),
            changed_parameters=self.parameters(changed),
            deleted_parameters=[],
        )

    def parameters(self, pairs: Sequence[tuple[str, RosValue]]) -> list[Any]:
        return [self.message("rcl_interfaces/msg/Parameter", name=name, value=self._value(value)) for name, value in pairs]

    def set_parameters_request(self, service: str, payload: bytes) -> list[tuple[str, RosValue]]:
        """The (name, value) pairs of a set request; a value not bool, int, float or str comes as its ParameterType."""
        out: list[tuple[str, RosValue]] = []
        for parameter in self.request(service, payload).parameters:
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

    def request(self, service: str, payload: bytes) -> Any:
        return self.decode(payload, f"{service}_Request")

    def twist(self, payload: bytes) -> Twist:
        """A Twist, read straight from the bytes by :mod:`.cdr` (taken on Zenoh's thread); anything odd by rosbags,
        which says what is wrong. PayloadError if invalid or not finite."""
        fast = cdr.twist_le(payload)
        if fast is not None and all(map(math.isfinite, fast)):
            return _as_twist(fast)
        return self._twist(payload, self.decode(payload, ros.TWIST))

    def twist_stamped(self, payload: bytes) -> tuple[Twist, float]:
        """The Twist and the header's stamp (Unix s; 0.0 for a zero stamp), read as :meth:`twist` reads a Twist."""
        fast = cdr.twist_stamped_le(payload)
        if fast is not None and all(map(math.isfinite, fast[2])):
            return _as_twist(fast[2]), fast[0] + fast[1] * 1e-9
        message = self.decode(payload, ros.TWIST_STAMPED)
        stamp = message.header.stamp
        return self._twist(payload, message.twist), stamp.sec + stamp.nanosec * 1e-9

    def _twist(self, payload: bytes, twist: Any) -> Twist:  # rosbags' message: the reference path, and its errors
        values = {f"{part}.{axis}": getattr(getattr(twist, part), axis) for part in ("linear", "angular") for axis in "xyz"}
        bad = [name for name, value in values.items() if not math.isfinite(value)]
        if bad:
            raise PayloadError("Twist", f"{', '.join(bad)} must be finite numbers, got {[values[b] for b in bad]}", excerpt(payload))
        return _as_twist(tuple(values.values()))

    def encode_twist(self, linear_x: float, angular_z: float, stamp: float | None = None, frame_id: str = "") -> bytes:
        linear, angular = self.vector3(linear_x, 0.0, 0.0), self.vector3(0.0, 0.0, angular_z)
        if stamp is None:
            return self.encode(ros.TWIST, linear=linear, angular=angular)
        return self.encode(
            ros.TWIST_STAMPED, header=self.header(stamp, frame_id), twist=self.message(ros.TWIST, linear=linear, angular=angular)
        )


def _as_twist(values: tuple[float, ...]) -> Twist:
    lx, ly, lz, ax, ay, az = values
    return Twist(linear=Vector3(x=lx, y=ly, z=lz), angular=Vector3(x=ax, y=ay, z=az))
