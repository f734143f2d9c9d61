"""The wheels as joints: their angles integrated from the impulses (``/joint_states``), and the robot model.

What robot_state_publisher would do for the URDF, without ROS: the fixed
joints once on ``/tf_static``, the two wheels on ``/tf`` turned by their
angles. Pure, ``now`` comes with each sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from blackmetal.robot_model import Encoders
from blackmetal.schemas import WheelImpulses

from .ros_types import Transform

#: Joint positions are not integrated across a gap longer than this (s): a lost link is not motion.
MAX_JOINT_GAP_S = 0.5


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


@dataclass(slots=True)
class WheelJoints:
    """Wheel angles (rad) integrated from wheel speeds, trapezoid rule, never across a gap."""

    encoders: Encoders
    radius: float
    positions: list[float] = field(default_factory=lambda: [0.0, 0.0])
    velocities: list[float] = field(default_factory=lambda: [0.0, 0.0])
    _last_time: float | None = None

    def feed(self, sample: WheelImpulses) -> None:
        left, right = self.encoders.to_speeds(float(sample.left), float(sample.right))
        velocities = [left / self.radius, right / self.radius]
        now = sample.mono if sample.mono is not None else sample.stamp
        if self._last_time is not None:
            dt = now - self._last_time
            if 0.0 < dt <= MAX_JOINT_GAP_S:
                for i in (0, 1):
                    self.positions[i] += 0.5 * (self.velocities[i] + velocities[i]) * dt
        self._last_time = now
        self.velocities = velocities
