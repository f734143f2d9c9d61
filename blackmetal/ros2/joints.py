"""The robot model as robot_state_publisher would publish it, without ROS: the fixed joints once on ``/tf_static``,
the two wheels on ``/tf`` turned by their angles (:class:`~blackmetal.robot_model.WheelAngles`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from .ros_types import Transform


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
