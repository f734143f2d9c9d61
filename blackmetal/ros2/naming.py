"""Where ROS 2 messages live on Zenoh: rmw_zenoh's keys, liveliness tokens, QoS and attachments per distro, and
zenoh-bridge-ros2dds's keys (raw CDR on the topic name, a service a queryable on its name).

Pure string and byte work, no Zenoh and no ROS. Each format, and the rmw_zenoh sources it was read from, is in
docs/ros2.md "What each distro writes"; :func:`topics` and :func:`services` list the node's entities.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from enum import StrEnum

from blackmetal.schemas import ConfigError

from . import ros_types as ros

ADMIN_SPACE = "@ros2_lv"
ENCLAVE = "/"  # the node's security enclave: the root one, as a node started without --enclave
ATTACHMENT_SIZE = 33
GID_SIZE = 16
_ATTACHMENT = struct.Struct("<qqB16s")

# rmw's enum values (rmw/types.h), as rmw_zenoh writes them into a QoS string.
RELIABILITY_RELIABLE, RELIABILITY_BEST_EFFORT = 1, 2
DURABILITY_TRANSIENT_LOCAL, DURABILITY_VOLATILE = 1, 2
HISTORY_KEEP_LAST, HISTORY_KEEP_ALL = 1, 2
#: rmw_zenoh's defaults: a value equal to its default is written as an empty field.
RMW_ZENOH_DEFAULTS = {"reliability": RELIABILITY_RELIABLE, "durability": DURABILITY_VOLATILE, "history": HISTORY_KEEP_LAST, "depth": 42}

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class Distro(StrEnum):
    """The ROS 2 distributions whose rmw_zenoh wire formats the adapter speaks."""

    HUMBLE = "humble"
    JAZZY = "jazzy"
    KILTED = "kilted"
    LYRICAL = "lyrical"
    ROLLING = "rolling"


#: Only Humble's missing type hashes differ on the wire; the rmw_zenoh releases each distro's formats were read from:
#: docs/ros2.md "What each distro writes".
WITHOUT_TYPE_HASHES = frozenset({Distro.HUMBLE})
#: What Humble's rmw_zenoh writes where later distros write the type hash.
TYPE_HASH_NOT_SUPPORTED = "TypeHashNotSupported"
#: Without ``--distro`` and without a sourced ROS (``ROS_DISTRO``): the current LTS.
DEFAULT_DISTRO = Distro.JAZZY


def parse_distros(text: str, origin: str = "--distro") -> tuple[Distro, ...]:
    """``"humble,jazzy"`` -> (HUMBLE, JAZZY), in the given order, each once; ConfigError in one sentence otherwise."""
    names = [part.strip().lower() for part in text.split(",") if part.strip()]
    if not names:
        raise ConfigError(f"{origin} names no ROS 2 distro; give one of {', '.join(d.value for d in Distro)} (or several, comma-separated)")
    for name in names:
        if name not in {d.value for d in Distro}:
            raise ConfigError(
                f"{origin} {name!r} is not a ROS 2 distro rmw_zenoh is released for: give {', '.join(d.value for d in Distro)} "
                "(or several, comma-separated, e.g. humble,jazzy)"
            )
    return tuple(dict.fromkeys(Distro(name) for name in names))


def type_hash_of(distro: Distro, computed: str) -> str:
    """The type hash ``distro``'s rmw_zenoh writes in keys and tokens: ``computed`` (RIHS01), or Humble's constant."""
    return TYPE_HASH_NOT_SUPPORTED if distro in WITHOUT_TYPE_HASHES else computed


class Flavor(StrEnum):
    RMW_ZENOH = "rmw_zenoh"
    BRIDGE = "bridge"


class Direction(StrEnum):
    PUBLISH = "MP"  # we publish: a ROS publisher in the graph
    SUBSCRIBE = "MS"  # we subscribe: a ROS subscription


class ServiceRole(StrEnum):
    SERVER = "SS"  # we answer: a ROS service server in the graph
    CLIENT = "SC"  # a ROS service client (what tests play)


@dataclass(frozen=True, slots=True)
class Qos:
    """The QoS a topic is declared with; the issue's default: reliable, volatile, keep-last 10."""

    reliability: int = RELIABILITY_RELIABLE
    durability: int = DURABILITY_VOLATILE
    history: int = HISTORY_KEEP_LAST
    depth: int = 10

    @property
    def is_transient_local(self) -> bool:
        return self.durability == DURABILITY_TRANSIENT_LOCAL

    def keyexpr(self) -> str:
        """rmw_zenoh's encoding (``qos_to_keyexpr``): ``::,10:,:,:,,`` for the default above."""
        fields = ("" if getattr(self, name) == default else str(getattr(self, name)) for name, default in RMW_ZENOH_DEFAULTS.items())
        reliability, durability, history, depth = fields
        return f"{reliability}:{durability}:{history},{depth}:,:,:,,"


#: ``rclcpp::QoS(1).transient_local()``: robot_state_publisher's /robot_description and tf2's StaticBroadcasterQoS.
TRANSIENT_LOCAL = Qos(durability=DURABILITY_TRANSIENT_LOCAL, depth=1)


def check_ros_name(kind: str, name: str) -> str:
    if not _NAME.match(name):
        raise ConfigError(f"{kind} {name!r} is not a valid ROS name: letters, digits and '_', not starting with a digit")
    return name


def normalise_namespace(namespace: str | None) -> str:
    """``r1``, ``/r1``, ``/r1/`` -> ``/r1``; none or empty -> ``/`` (ROS's root namespace)."""
    parts = [check_ros_name("namespace part", p) for p in (namespace or "").split("/") if p]
    return "/" + "/".join(parts)


def full_topic(namespace: str, topic: str) -> str:
    base = namespace.rstrip("/")
    return f"{base}/{topic.strip('/')}"


def tf_frame_prefix(namespace: str) -> str:
    """diff_drive_controller's frame prefix from its namespace (``resolve_tf_prefix`` with the defaults):
    ``/r3`` -> ``r3/``, ``/`` -> none."""
    prefix = namespace if namespace.endswith("/") else namespace + "/"
    return prefix.removeprefix("/")


def dds_type(ros_type: str) -> str:
    """``geometry_msgs/msg/Twist`` -> ``geometry_msgs::msg::dds_::Twist_`` (the name rmw_zenoh puts in keys)."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def mangle(name: str) -> str:
    """rmw_zenoh's ``mangle_name``: every ``/`` becomes ``%`` so a name is one key chunk."""
    return name.replace("/", "%")


def rmw_zenoh_data_key(domain_id: int, topic: str, ros_type: str, type_hash: str) -> str:
    return f"{domain_id}/{topic.strip('/')}/{dds_type(ros_type)}/{type_hash}"


@dataclass(frozen=True, slots=True)
class NodeIdentity:
    """Who we are in the ROS graph: domain, Zenoh session id, node name and namespace (in the root enclave, ``/``)."""

    domain_id: int
    zid: str
    name: str
    namespace: str = "/"
    node_id: int = 0

    def _head(self, entity_id: int, kind: str) -> str:
        return (
            f"{ADMIN_SPACE}/{self.domain_id}/{self.zid}/{self.node_id}/{entity_id}/{kind}/"
            f"{mangle(ENCLAVE)}/{mangle(self.namespace)}/{mangle(self.name)}"
        )

    def node_token(self) -> str:
        return self._head(self.node_id, "NN")

    def entity_token(self, entity_id: int, kind: Direction | ServiceRole, topic: str, ros_type: str, type_hash: str, qos: Qos) -> str:
        """A topic's (``MP``/``MS``) or a service's (``SS``/``SC``) token; ``topic``: the fully qualified name."""
        return f"{self._head(entity_id, kind.value)}/{mangle(topic)}/{dds_type(ros_type)}/{type_hash}/{qos.keyexpr()}"


def gid_of(token: str) -> bytes:
    """An entity's 16-byte GID as rmw_zenoh computes it: XXH3-128 of its liveliness token, low half first."""
    import xxhash

    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(GID_SIZE, "little")


def attachment(sequence: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """The 33-byte attachment every rmw_zenoh subscriber requires on a sample."""
    return _ATTACHMENT.pack(sequence, source_timestamp_ns, GID_SIZE, gid)


def parse_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(sequence, source timestamp ns, gid) from an rmw_zenoh attachment; ValueError if it is not one."""
    if len(data) != ATTACHMENT_SIZE or data[16] != GID_SIZE:
        raise ValueError(f"an rmw_zenoh attachment is {ATTACHMENT_SIZE} bytes with a length byte 16, got {len(data)} bytes")
    sequence, stamp, _, gid = _ATTACHMENT.unpack(data)
    return sequence, stamp, gid


@dataclass(frozen=True, slots=True)
class RosTopic:
    """One ROS topic of the node: its name (relative to the namespace unless ``absolute``), its type, which way it flows."""

    name: str
    ros_type: str
    direction: Direction
    absolute: bool = False
    #: How the node's keys and ready line name it, where one topic takes two types (``cmd_vel_stamped``); default ``name``.
    label: str = ""
    qos: Qos = Qos()

    @property
    def key_name(self) -> str:
        return self.label or self.name

    def full_name(self, namespace: str) -> str:
        return f"/{self.name}" if self.absolute else full_topic(namespace, self.name)


@dataclass(frozen=True, slots=True)
class RosService:
    """One ROS service the node serves; ``private``: under the node's name (``~/name``)."""

    name: str
    ros_type: str
    private: bool = False
    qos: Qos = Qos()

    def full_name(self, namespace: str, node_name: str) -> str:
        return full_topic(full_topic(namespace, node_name) if self.private else namespace, self.name)


#: The key name of ``/cmd_vel`` as ``geometry_msgs/TwistStamped`` (``cmd_vel`` is the Twist).
CMD_VEL_STAMPED = "cmd_vel_stamped"
ROBOT_DESCRIPTION = "robot_description"
TF_STATIC = "tf_static"


def topics(publish_tf: bool, absolute_tf: bool = False, robot_model: bool = False) -> list[RosTopic]:
    """The node's topics, in the order their entities are numbered (docs/ros2-adapter.md "Topics and services").

    ``/cmd_vel`` is subscribed as Twist and as TwistStamped (the type is in the key); the stamped one comes after
    the others so they keep their entity ids. ``absolute_tf``: one ``/tf`` tree for a fleet.
    """
    out = [
        RosTopic("cmd_vel", ros.TWIST, Direction.SUBSCRIBE),
        RosTopic("estop", ros.BOOL, Direction.SUBSCRIBE),
        RosTopic("odom", ros.ODOMETRY, Direction.PUBLISH),
    ]
    if publish_tf:
        out.append(RosTopic("tf", ros.TF_MESSAGE, Direction.PUBLISH, absolute=absolute_tf))
    out.append(RosTopic("joint_states", ros.JOINT_STATE, Direction.PUBLISH))
    out.append(RosTopic("diagnostics", ros.DIAGNOSTIC_ARRAY, Direction.PUBLISH, absolute=True))
    out.append(RosTopic("cmd_vel", ros.TWIST_STAMPED, Direction.SUBSCRIBE, label=CMD_VEL_STAMPED))
    if robot_model:
        out.append(RosTopic(ROBOT_DESCRIPTION, ros.STRING, Direction.PUBLISH, qos=TRANSIENT_LOCAL))
        out.append(RosTopic(TF_STATIC, ros.TF_MESSAGE, Direction.PUBLISH, absolute=absolute_tf, qos=TRANSIENT_LOCAL))
    out.append(RosTopic(PARAMETER_EVENTS, ros.PARAMETER_EVENT, Direction.PUBLISH, absolute=True, qos=PARAMETERS_QOS))
    return out


SET_ESTOP = "set_estop"
RESET_ODOMETRY = "reset_odometry"
PARAMETER_EVENTS = "parameter_events"
#: rclcpp's parameter services, ``~/<name>``, in the order rclcpp's ParameterService creates them.
PARAMETER_SERVICES = {
    "get_parameters": ros.GET_PARAMETERS,
    "get_parameter_types": ros.GET_PARAMETER_TYPES,
    "set_parameters": ros.SET_PARAMETERS,
    "set_parameters_atomically": ros.SET_PARAMETERS_ATOMICALLY,
    "describe_parameters": ros.DESCRIBE_PARAMETERS,
    "list_parameters": ros.LIST_PARAMETERS,
}
#: rmw_qos_profile_parameters and rmw_qos_profile_parameter_events (rmw/qos_profiles.h): keep-last 1000, reliable, volatile.
PARAMETERS_QOS = Qos(depth=1000)


def services() -> list[RosService]:
    """The node's services, numbered after its topics; rclcpp's parameter services under the node's name."""
    return [
        RosService(SET_ESTOP, ros.SET_BOOL),
        RosService(RESET_ODOMETRY, ros.TRIGGER),
        *(RosService(name, ros_type, private=True, qos=PARAMETERS_QOS) for name, ros_type in PARAMETER_SERVICES.items()),
    ]


def check_source_name(name: str) -> str:
    if not re.match(r"^[A-Za-z0-9_-]+$", name):
        raise ConfigError(f"source {name!r} must be letters, digits, '_' or '-' (one key chunk, e.g. ros2)")
    return name
