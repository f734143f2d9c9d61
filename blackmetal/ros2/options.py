"""What a :class:`~blackmetal.ros2.core.Ros2Core` is given: its options (the robot model among them), and where its messages go.

Apart from the core so that its parts (:mod:`.diagnostics`, :mod:`.calls`) read them without importing the core.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol

from blackmetal.robot_model import Encoders
from blackmetal.schemas import ErrorReport, Sources

from .ros_types import Frames, Transform


@dataclass(frozen=True, slots=True)
class Wheel:
    """A wheel's transform from ``/joint_states``: ``parent`` -> ``child`` at ``y`` (m), turned about +y by its angle."""

    parent: str
    child: str
    y: float

    def transform(self, angle: float) -> Transform:
        return Transform(self.parent, self.child, (0.0, self.y, 0.0), (0.0, math.sin(angle / 2), 0.0, math.cos(angle / 2)))


@dataclass(frozen=True, slots=True)
class RobotModel:
    """What robot_state_publisher would publish for the URDF: the text, its fixed joints, its two wheels (left, right)."""

    urdf: str
    fixed: tuple[Transform, ...]
    wheels: tuple[Wheel, Wheel]
    #: Publish the wheels' transforms on /tf from the wheel angles (robot_state_publisher's job for moving joints).
    wheel_tf: bool = True


class Ros2Output(Protocol):
    """Where the core's messages go: ROS topics, blackmetal keys, error reports, service answers and queries."""

    def ros(self, topic: str, cdr: bytes) -> None: ...
    def blackmetal(self, key: str, payload: bytes) -> None: ...
    def error(self, message: ErrorReport) -> None: ...
    def service_reply(self, call: int, cdr: bytes, attachment: bytes | None) -> None: ...
    def service_refuse(self, call: int, reason: str) -> None:
        """Answer ``call`` with a Zenoh error reply: it carries no usable request id to answer with a response."""

    def query(self, key: str, payload: bytes | None, tag: int, timeout: float) -> None:
        """``get`` on ``key``; each reply comes back as ``on_query_reply(tag, ...)``, then ``on_query_done(tag)``."""

    def follow(self, streams: frozenset[str]) -> None:
        """Subscribe to exactly these of the robot's streams (``pose``, ``impulses``, ``errors``, ``health``, ``nav_feedback``), no others."""


@dataclass(frozen=True, slots=True)
class Ros2Options:
    """The core's settings, as :meth:`~.settings.Ros2Settings.options` makes them (what each means: its help there)."""

    frames: Frames
    pose_covariance: list[float]
    twist_covariance: list[float]
    publish_tf: bool
    joint_names: tuple[str, str]
    wheel_radius: float
    encoders: Encoders
    #: How error reports name the ROS inputs and services: the Zenoh key of each (by topic or service name).
    data_keys: Mapping[str, str] = field(default_factory=dict)
    service_keys: Mapping[str, str] = field(default_factory=dict)
    source: str = Sources.ROS2
    service_timeout: float = 2.0
    expected_poll_hz: float = 50.0
    #: For the diagnostics: the node's fully qualified name, the flavour, the domain, the distro.
    node: str = "/blackmetal"
    flavor: str = "rmw_zenoh"
    domain_id: int = 0
    distro: str = "jazzy"
    #: /robot_description, /tf_static and the wheels on /tf; None: another node publishes the robot model.
    robot: RobotModel | None = None
    #: For the diagnostics: the calibration in use and where /odom's covariance comes from.
    calibration: str = "none: the nominal constants"
    covariance: str = "fixed diagonals (--pose-covariance-diagonal, --twist-covariance-diagonal)"
    #: NavigateToPose's layout on the node's distro (:class:`~.action_types.NavLayout`).
    nav_layout: str = "jazzy"
    #: free_fleet's plain keys under this robot name ("": off), its frames (never prefixed) and battery (0..1 or None).
    rmf_name: str = ""
    rmf_frames: Frames = field(default_factory=Frames)
    rmf_battery: float | None = None
