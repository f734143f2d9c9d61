"""The robot in the 3D panel: its URDF, and the wheels turning (pure); docs/foxglove.md ("The robot model").

The panel places URDF links by the transforms it receives, so the wheels turn through transforms: :class:`WheelAngles`
integrates each wheel's angle from the impulses. The joints are read from the URDF text itself, so they cannot
disagree with what the panel draws.
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Any

from blackmetal import robot_model as model
from blackmetal.robot_model import Encoders, WheelAngles
from blackmetal.schemas import ConfigError, GatewayParams, stamp_parts

from .channels import HEADER, array, message_schema, typed

#: ROS's std_msgs/msg/String as JSON: what the 3D panel's URDF layer reads.
STRING_SCHEMA = message_schema("std_msgs/msg/String", "the robot's URDF (blackmetal.robot_model.urdf)", {"data": typed("string")}, ["data"])

_NUMBERS = array(typed("number"))
#: ROS's sensor_msgs/msg/JointState as JSON.
JOINT_STATE_SCHEMA = message_schema(
    "sensor_msgs/msg/JointState",
    "the wheel joints' angles (rad) and speeds (rad/s), integrated from <prefix>/wheels/impulses",
    {"header": HEADER, "name": array(typed("string")), "position": _NUMBERS, "velocity": _NUMBERS, "effort": _NUMBERS},
)


@dataclass(frozen=True, slots=True)
class Joint:
    """A moving joint of the URDF: what the panel needs to turn its child link."""

    name: str
    parent: str
    child: str
    origin: tuple[float, float, float]
    axis: tuple[float, float, float]


def _floats(text: str | None, default: tuple[float, float, float]) -> tuple[float, float, float]:
    x, y, z = (float(part) for part in text.split()) if text else default
    return x, y, z


def moving_joints(urdf_text: str) -> list[Joint]:
    return _joints(urdf_text, ("continuous", "revolute"))


def fixed_joints(urdf_text: str) -> list[Joint]:
    """The URDF's fixed joints (``base_footprint -> base_link``, the caster): sent on /tf as they are, so the frame tree
    is whole with or without a URDF layer in the panel (their ``rpy`` is zero in the robot model's URDF)."""
    return _joints(urdf_text, ("fixed",))


def _joints(urdf_text: str, types: tuple[str, ...]) -> list[Joint]:
    joints = []
    for element in ET.fromstring(urdf_text).iter("joint"):
        parent, child = element.find("parent"), element.find("child")
        if element.get("type") not in types or parent is None or child is None:
            continue
        origin, axis = element.find("origin"), element.find("axis")
        joints.append(
            Joint(
                element.get("name", ""),
                parent.get("link", ""),
                child.get("link", ""),
                _floats(origin.get("xyz") if origin is not None else None, (0.0, 0.0, 0.0)),
                _floats(axis.get("xyz") if axis is not None else None, (1.0, 0.0, 0.0)),
            )
        )
    return joints


def _param(params: GatewayParams, name: str) -> float | None:
    for param in params.params:
        if param.name == name and isinstance(param.value, (int, float)) and not isinstance(param.value, bool):
            return float(param.value)
    return None


class RobotModel:
    """One robot's URDF (frame-prefixed) and its wheel joints; rebuilt when the gateway's wheel geometry is known."""

    def __init__(self, frame_prefix: str = "", encoders: Encoders | None = None) -> None:
        self.frame_prefix = frame_prefix
        self.encoders = encoders or Encoders()
        self.body = model.Body()
        self._build()

    def _build(self) -> None:
        self.urdf = model.urdf(self.body, frame_prefix=self.frame_prefix)
        self.joints = moving_joints(self.urdf)
        self.fixed = fixed_joints(self.urdf)
        wheels = {joint.child.removeprefix(self.frame_prefix): joint for joint in self.joints}
        self.left, self.right = wheels.get("left_wheel"), wheels.get("right_wheel")

    def on_params(self, params: GatewayParams) -> bool:
        """The gateway's parameters: its wheel geometry and calibrated encoders. True when the URDF changed."""
        separation = _param(params, "wheel_separation") or self.body.wheel_separation
        radius = _param(params, "wheel_radius") or self.body.wheel_radius
        left, right = _param(params, "impulses_left"), _param(params, "impulses_right")
        if left and right and left > 0 and right > 0:
            self.encoders = Encoders(left, right, self.encoders.mirror_right)
        if (separation, radius) == (self.body.wheel_separation, self.body.wheel_radius):
            return False
        try:
            body = model.Body(wheel_separation=separation, wheel_radius=radius).check()
        except ConfigError:
            return False  # the gateway's own checks keep these sane; the view keeps the model it has
        self.body = body
        self._build()
        return True

    def description(self) -> bytes:
        return json.dumps({"data": self.urdf}).encode()


def joint_state(robot: RobotModel, angles: WheelAngles, stamp: float) -> dict[str, Any]:
    sec, nsec = stamp_parts(stamp)
    names = [joint.name for joint in (robot.left, robot.right) if joint is not None]
    return {
        "header": {"stamp": {"sec": sec, "nsec": nsec}, "frame_id": ""},
        "name": names,
        "position": list(angles.positions[: len(names)]),
        "velocity": list(angles.velocities[: len(names)]),
        "effort": [],
    }


def turned(joint: Joint, angle: float) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """The joint's transform at ``angle``: its origin, and the rotation about its axis as a quaternion (x, y, z, w)."""
    ax, ay, az = joint.axis
    norm = math.sqrt(ax * ax + ay * ay + az * az) or 1.0
    s = math.sin(angle / 2) / norm
    return joint.origin, (ax * s, ay * s, az * s, math.cos(angle / 2))
