"""``blackmetal ros2`` settings: one typed model, the same precedence rules as every service."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

from blackmetal import robot_model as model
from blackmetal.robot_model import Encoders
from blackmetal.runtime.settings import check_positive, setting
from blackmetal.runtime.zenoh_setup import ZenohSettings
from blackmetal.schemas import DEFAULT_PREFIX, ConfigError, Sources, validate_prefix

from .core import Ros2Options
from .messages import Frames
from .naming import CMD_VEL_STAMPED, Flavor, check_ros_name, check_source_name, full_topic, normalise_namespace

#: diff_drive_controller's example configuration: x, y, z, roll, pitch, yaw.
DEFAULT_COVARIANCE = "0.001,0.001,0.001,0.001,0.001,0.01"


def _domain_default() -> int:
    try:
        return int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
    except ValueError:
        return -1  # reported by check()


def diagonal_matrix(text: str, name: str) -> list[float]:
    """``"a,b,c,d,e,f"`` -> the row-major 6x6 covariance with that diagonal."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise ConfigError(f"{name} must be six comma-separated numbers, got {text!r}") from None
    if len(values) != 6 or not all(math.isfinite(v) and v >= 0 for v in values):
        raise ConfigError(f"{name} must be six comma-separated non-negative numbers (x,y,z,roll,pitch,yaw), got {text!r}")
    matrix = [0.0] * 36
    for i, value in enumerate(values):
        matrix[7 * i] = value
    return matrix


@dataclass(slots=True)
class Ros2Settings:
    flavor: str = setting(
        Flavor.RMW_ZENOH.value, "rmw_zenoh (ROS 2's Zenoh middleware) or bridge (zenoh-bridge-ros2dds)", choices=["rmw_zenoh", "bridge"]
    )
    # the helper appends "(default X)" to every help text: none of these says it again
    domain_id: int = setting(factory=_domain_default, help="ROS domain id; ROS_DOMAIN_ID when set, else 0", metavar="N")
    namespace: str = setting("/", "ROS namespace of the node, its topics and services, e.g. r1 (/ is none)", metavar="NS")
    node_name: str = setting("blackmetal", "ROS node name", metavar="NAME")
    prefix: str = setting(DEFAULT_PREFIX, "blackmetal key-expression prefix of the robot, e.g. fleet/a")
    source: str = setting(
        Sources.ROS2, "command source /cmd_vel drives as: <prefix>/cmd_vel/NAME (the gateway must know it: its --source)", metavar="NAME"
    )
    service_timeout: float = setting(2.0, "set_estop and reset_odometry answer success=false unless confirmed within this", metavar="S")
    expected_poll_hz: float = setting(
        50.0, "the gateway's --poll-hz, which /diagnostics holds the measured poll rate against", metavar="HZ"
    )
    odom_frame: str = setting("odom", "frame of /odom and parent of the transform", metavar="FRAME")
    base_frame: str = setting("base_link", "child frame of /odom and of the transform", metavar="FRAME")
    tf: bool = setting(True, "do not publish /tf (when another node publishes odom -> base_link)", flag="--no-tf", const=False)
    twist_stamped: bool = setting(
        False,
        "no effect, kept so that older settings files load: /cmd_vel takes geometry_msgs/Twist and TwistStamped at once",
    )
    pose_covariance_diagonal: str = setting(DEFAULT_COVARIANCE, "six variances x,y,z,roll,pitch,yaw of /odom's pose", metavar="LIST")
    twist_covariance_diagonal: str = setting(DEFAULT_COVARIANCE, "six variances of /odom's twist", metavar="LIST")
    left_joint: str = setting("left_wheel_joint", "name of the left wheel in /joint_states", metavar="NAME")
    right_joint: str = setting("right_wheel_joint", "name of the right wheel in /joint_states", metavar="NAME")
    wheel_radius: float = setting(model.WHEEL_RADIUS, "wheel radius for /joint_states angles, m", metavar="M")
    impulses_left: float = setting(model.IMPULSES_PER_METER_LEFT, "impulses per metre, left wheel", metavar="N")
    impulses_right: float = setting(model.IMPULSES_PER_METER_RIGHT, "impulses per metre, right wheel", metavar="N")
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)

    def check(self) -> None:
        validate_prefix(self.prefix)
        if self.domain_id == -1 and os.environ.get("ROS_DOMAIN_ID"):
            raise ConfigError(f"ROS_DOMAIN_ID must be a number 0..232, got {os.environ['ROS_DOMAIN_ID']!r}")
        if not 0 <= self.domain_id <= 232:
            raise ConfigError(f"ROS domain id must be 0..232, got {self.domain_id} (check --domain-id or ROS_DOMAIN_ID)")
        check_ros_name("node name", self.node_name)
        normalise_namespace(self.namespace)
        check_source_name(self.source)
        check_positive(service_timeout=self.service_timeout, expected_poll_hz=self.expected_poll_hz)
        diagonal_matrix(self.pose_covariance_diagonal, "pose_covariance_diagonal")
        diagonal_matrix(self.twist_covariance_diagonal, "twist_covariance_diagonal")
        for name in ("wheel_radius", "impulses_left", "impulses_right"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("odom_frame", "base_frame", "left_joint", "right_joint"):
            if not getattr(self, name):
                raise ConfigError(f"{name} must not be empty")

    @property
    def encoders(self) -> Encoders:
        return Encoders(self.impulses_left, self.impulses_right)

    def options(self, data_keys: dict[str, str], service_keys: dict[str, str] | None = None, frame_prefix: str = "") -> Ros2Options:
        """The core's options; ``data_keys``/``service_keys``: the Zenoh key of each ROS topic/service, which error reports name;
        ``frame_prefix`` goes before both frames (``r3/``: ``r3/odom``, ``r3/base_link``)."""
        return Ros2Options(
            frames=Frames(frame_prefix + self.odom_frame, frame_prefix + self.base_frame),
            pose_covariance=diagonal_matrix(self.pose_covariance_diagonal, "pose_covariance_diagonal"),
            twist_covariance=diagonal_matrix(self.twist_covariance_diagonal, "twist_covariance_diagonal"),
            publish_tf=self.tf,
            joint_names=(self.left_joint, self.right_joint),
            wheel_radius=self.wheel_radius,
            encoders=self.encoders,
            cmd_vel_key=data_keys["cmd_vel"],
            cmd_vel_stamped_key=data_keys.get(CMD_VEL_STAMPED, "cmd_vel"),
            estop_key=data_keys["estop"],
            source=self.source,
            service_timeout=self.service_timeout,
            expected_poll_hz=self.expected_poll_hz,
            node=full_topic(normalise_namespace(self.namespace), self.node_name),
            flavor=self.flavor,
            domain_id=self.domain_id,
            service_keys=dict(service_keys or {}),
        )
