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

from .action_types import layout_of
from .naming import (
    DEFAULT_DISTRO,
    Distro,
    Flavor,
    check_ros_name,
    check_source_name,
    full_topic,
    normalise_namespace,
    parse_distros,
)
from .options import RobotModel, Ros2Options, Wheel
from .ros_types import Frames, Transform

#: diff_drive_controller's example configuration: x, y, z, roll, pitch, yaw.
DEFAULT_COVARIANCE = "0.001,0.001,0.001,0.001,0.001,0.01"
#: A variance made of a calibration's residual is never below this: a perfect fit is not a certain pose (1 mm, 1 mrad).
MIN_VARIANCE = 1e-6
#: The URDF's root link: the odometry's child frame when the adapter publishes the robot model.
ROOT_LINK = "base_footprint"


def _distro_default() -> str:
    """The distro of a sourced ROS 2 setup (it exports ROS_DISTRO), else the current LTS."""
    return os.environ.get("ROS_DISTRO", "").strip() or DEFAULT_DISTRO.value


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
    distro: str = setting(
        factory=_distro_default,
        help="ROS 2 distro whose rmw_zenoh wire formats the node speaks: humble, jazzy, kilted, lyrical or rolling, or "
        "several comma-separated (humble,jazzy: one node each, on one robot); ROS_DISTRO when set, else jazzy",
        metavar="NAME[,NAME]",
    )
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
    base_frame: str = setting(
        ROOT_LINK, "child frame of /odom and of the transform (the URDF's root link, unless --no-robot-model)", metavar="FRAME"
    )
    tf: bool = setting(True, "do not publish /tf (when another node publishes odom -> base_link)", flag="--no-tf", const=False)
    twist_stamped: bool = setting(
        False,
        "no effect, kept so that older settings files load: /cmd_vel takes geometry_msgs/Twist and TwistStamped at once",
    )
    pose_covariance_diagonal: str = setting(DEFAULT_COVARIANCE, "six variances x,y,z,roll,pitch,yaw of /odom's pose", metavar="LIST")
    twist_covariance_diagonal: str = setting(DEFAULT_COVARIANCE, "six variances of /odom's twist", metavar="LIST")
    left_joint: str = setting("left_wheel_joint", "name of the left wheel in /joint_states", metavar="NAME")
    right_joint: str = setting("right_wheel_joint", "name of the right wheel in /joint_states", metavar="NAME")
    wheel_radius: float = setting(model.WHEEL_RADIUS, "wheel radius for /joint_states angles and the URDF, m", metavar="M")
    wheel_separation: float = setting(model.WHEEL_SEPARATION, "distance between the wheels for the URDF, m", metavar="M")
    robot_model: bool = setting(
        True,
        "publish no robot_description, tf_static or wheel transforms (when robot_state_publisher publishes the robot's URDF)",
        flag="--no-robot-model",
        const=False,
    )
    calibration: str = setting(
        "",
        "calibration file of blackmetal calibrate -o: its constants (for /joint_states and the URDF) and its measured "
        "residuals (for /odom's covariance), in place of the ones set here",
        metavar="FILE",
    )
    impulses_left: float = setting(model.IMPULSES_PER_METER_LEFT, "impulses per metre, left wheel", metavar="N")
    impulses_right: float = setting(model.IMPULSES_PER_METER_RIGHT, "impulses per metre, right wheel", metavar="N")
    rmf: bool = setting(
        False,
        "serve Open-RMF free_fleet's Nav2 robot adapter on plain keys under the robot's RMF name: <name>/tf, "
        "<name>/navigate_to_pose/_action/*, <name>/battery_state (docs/open-rmf.md)",
    )
    rmf_name: str = setting(
        "", "the robot's name in free_fleet's config (its key prefix); empty: the last chunk of --prefix", metavar="NAME"
    )
    rmf_battery: float = setting(
        -1.0,
        "with --rmf: publish <name>/battery_state with this charge, 0..1 (a robot with no battery gauge); negative: none",
        metavar="FRACTION",
    )
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)

    def rmf_robot(self) -> str:
        """The robot's name in free_fleet's config: ``rmf_name``, else the last chunk of the prefix (``fleet/r1`` -> ``r1``)."""
        return self.rmf_name or self.prefix.rstrip("/").rsplit("/", 1)[-1]

    def distros(self) -> tuple[Distro, ...]:
        """The distros to serve, one node each (ConfigError naming ROS_DISTRO when the value came from it)."""
        from_env = os.environ.get("ROS_DISTRO", "").strip()
        return parse_distros(self.distro, "ROS_DISTRO" if from_env and self.distro == from_env else "--distro")

    def load_calibration(self) -> model.Calibration | None:
        return model.read_calibration(self.calibration) if self.calibration else None

    def check(self) -> None:
        validate_prefix(self.prefix)
        self.distros()
        self.load_calibration()
        if self.robot_model and self.base_frame != ROOT_LINK:
            raise ConfigError(
                f"--base-frame {self.base_frame}: the robot model's root link is {ROOT_LINK}, which /odom must name "
                "(give --no-robot-model when another node publishes your own URDF)"
            )
        if self.domain_id == -1 and os.environ.get("ROS_DOMAIN_ID"):
            raise ConfigError(f"ROS_DOMAIN_ID must be a number 0..232, got {os.environ['ROS_DOMAIN_ID']!r}")
        if not 0 <= self.domain_id <= 232:
            raise ConfigError(f"ROS domain id must be 0..232, got {self.domain_id} (check --domain-id or ROS_DOMAIN_ID)")
        check_ros_name("node name", self.node_name)
        normalise_namespace(self.namespace)
        check_source_name(self.source)
        check_positive(self, "service_timeout expected_poll_hz")
        if self.rmf:
            try:
                validate_prefix(self.rmf_robot())  # one or more key chunks, no wildcards
            except ConfigError as exc:
                raise ConfigError(f"rmf_name {self.rmf_robot()!r} cannot head free_fleet's keys: {exc}") from None
            if self.flavor == Flavor.BRIDGE.value and normalise_namespace(self.namespace).strip("/") == self.rmf_robot():
                raise ConfigError(
                    f"--rmf with the bridge flavour in namespace {self.namespace!r} would serve free_fleet's keys "
                    f"{self.rmf_robot()}/... twice: give --rmf-name another name, or drop --rmf"
                )
        if not (self.rmf_battery < 0 or 0.0 <= self.rmf_battery <= 1.0) or not math.isfinite(self.rmf_battery):
            raise ConfigError(f"rmf_battery is a charge 0..1 (negative: no battery), got {self.rmf_battery!r}")
        self.covariances(None)  # both diagonals parse
        check_positive(self, "wheel_radius wheel_separation impulses_left impulses_right")
        for name in ("odom_frame", "base_frame", "left_joint", "right_joint"):
            if not getattr(self, name):
                raise ConfigError(f"{name} must not be empty")

    def covariances(self, calibration: model.Calibration | None) -> tuple[list[float], list[float], str]:
        """/odom's pose and twist covariances and where they come from: a calibration's residuals (x, y, yaw; v, w)
        where it measured them, the configured diagonals for the rest."""
        pose = diagonal_matrix(self.pose_covariance_diagonal, "pose_covariance_diagonal")
        twist = diagonal_matrix(self.twist_covariance_diagonal, "twist_covariance_diagonal")
        if calibration is None or calibration.residuals is None:
            why = "fixed diagonals (--pose-covariance-diagonal, --twist-covariance-diagonal)"
            if calibration is not None:
                why += f": {calibration.path} holds no residuals (a UMBmark calibration measures none)"
            return pose, twist, why
        r = calibration.residuals
        for matrix, index, value in (
            (pose, 0, r.x_m),
            (pose, 7, r.y_m),
            (pose, 35, r.yaw_rad),
            (twist, 0, r.v_mps),
            (twist, 35, r.w_radps),
        ):
            matrix[index] = max(value * value, MIN_VARIANCE)
        why = (
            f"x, y, yaw, v, w from the residuals of {calibration.path} over {r.path_m:.1f} m (rms x {1000 * r.x_m:.1f} mm, "
            f"y {1000 * r.y_m:.1f} mm, yaw {r.yaw_rad:.4f} rad, v {1000 * r.v_mps:.1f} mm/s, w {r.w_radps:.4f} rad/s)"
        )
        return pose, twist, why

    def robot(self, separation: float, frame_prefix: str) -> RobotModel | None:
        """The robot model as robot_state_publisher would publish it: the URDF, its fixed joints, its wheels, prefixed."""
        if not self.robot_model:
            return None
        body = model.Body(wheel_separation=separation, wheel_radius=self.wheel_radius)
        joints = model.joints(body, left_joint=self.left_joint, right_joint=self.right_joint)
        p = frame_prefix
        fixed = tuple(Transform(p + j.parent, p + j.child, j.xyz) for j in joints if j.kind == "fixed")
        left, right = (Wheel(p + j.parent, p + j.child, j.xyz[1]) for j in joints if j.kind == "continuous")
        text = model.urdf(body, left_joint=self.left_joint, right_joint=self.right_joint, frame_prefix=p)
        return RobotModel(text, fixed, (left, right), wheel_tf=self.tf)

    def options(
        self,
        data_keys: dict[str, str],
        service_keys: dict[str, str] | None = None,
        frame_prefix: str = "",
        distro: Distro = DEFAULT_DISTRO,
    ) -> Ros2Options:
        """The core's options; ``data_keys``/``service_keys``: the Zenoh key of each ROS topic/service, which error reports name;
        ``frame_prefix`` goes before every frame (``r3/``: ``r3/odom``, ``r3/base_footprint``, the URDF's links)."""
        calibration = self.load_calibration()
        constants = calibration or self  # wheel_separation, impulses_left, impulses_right
        pose, twist, covariance = self.covariances(calibration)
        return Ros2Options(
            frames=Frames(frame_prefix + self.odom_frame, frame_prefix + self.base_frame),
            pose_covariance=pose,
            twist_covariance=twist,
            publish_tf=self.tf,
            joint_names=(self.left_joint, self.right_joint),
            wheel_radius=self.wheel_radius,
            encoders=Encoders(constants.impulses_left, constants.impulses_right),
            data_keys=dict(data_keys),
            source=self.source,
            service_timeout=self.service_timeout,
            expected_poll_hz=self.expected_poll_hz,
            node=full_topic(normalise_namespace(self.namespace), self.node_name),
            flavor=self.flavor,
            domain_id=self.domain_id,
            service_keys=dict(service_keys or {}),
            distro=distro.value if self.flavor == Flavor.RMW_ZENOH.value else "any (zenoh-bridge-ros2dds)",
            robot=self.robot(constants.wheel_separation, frame_prefix),
            calibration=f"{calibration.path} ({calibration.note})" if calibration else "none: the nominal constants",
            covariance=covariance,
            nav_layout=layout_of(distro).value,
            rmf_name=self.rmf_robot() if self.rmf else "",
            rmf_frames=Frames(self.odom_frame, self.base_frame),
            rmf_battery=self.rmf_battery if self.rmf_battery >= 0 else None,
        )
