"""The robot in the 3D panel: the URDF's wheel joints, and the wheels turning with the impulses (pure)."""

from __future__ import annotations

import math

import pytest

from blackmetal.foxglove.model import RobotModel, fixed_joints, moving_joints, turned
from blackmetal.robot_model import WHEEL_SEPARATION, WheelAngles, urdf
from blackmetal.schemas import GatewayParams, WheelImpulses
from unit.foxglove.test_params import table


def test_the_wheel_joints_come_from_the_urdf_and_turn_with_the_impulses() -> None:
    robot = RobotModel("r2/")
    assert robot.urdf == urdf(robot.body, frame_prefix="r2/")
    assert [(j.name, j.parent, j.child) for j in moving_joints(robot.urdf)] == [
        ("left_wheel_joint", "r2/base_link", "r2/left_wheel"),
        ("right_wheel_joint", "r2/base_link", "r2/right_wheel"),
    ]
    assert robot.left is not None and robot.left.origin == (0.0, WHEEL_SEPARATION / 2, 0.0) and robot.left.axis == (0.0, 1.0, 0.0)
    assert robot.on_params(GatewayParams(stamp=1.0, params=table(separation=0.6))), "a new wheel separation is a new URDF"
    assert robot.left.origin == (0.0, 0.3, 0.0) and 'xyz="0 0.3 0"' in robot.urdf
    assert not robot.on_params(GatewayParams(stamp=2.0, params=table(separation=0.6)))

    angles = WheelAngles(wrap=True)
    per_metre = robot.encoders.impulses_per_meter_left
    for i in range(51):  # 1 s at 50 Hz, the left wheel at 0.1 m/s forward, the right standing
        angles.feed(WheelImpulses(seq=i, stamp=i * 0.02, left=round(0.1 * per_metre), right=0, mono=i * 0.02), robot.encoders, 0.1)
    travel = round(0.1 * per_metre) / per_metre  # m in 1 s, as the impulses say
    assert angles.positions[0] == pytest.approx(travel / 0.1) and angles.positions[1] == 0.0  # about 0.1 m on a 0.1 m radius: 1 rad
    angles.feed(WheelImpulses(seq=99, stamp=5.0, left=10_000, right=0, mono=5.0), robot.encoders, 0.1)
    assert angles.positions[0] == pytest.approx(travel / 0.1), "never integrated across a gap"
    _, (qx, qy, qz, qw) = turned(robot.left, math.pi)
    assert (qx, qz) == (0.0, 0.0) and qy == pytest.approx(1.0) and abs(qw) < 1e-12


def test_the_fixed_joints_place_base_link_on_base_footprint_and_the_caster() -> None:
    robot = RobotModel("r2/")
    assert [(j.name, j.parent, j.child) for j in fixed_joints(robot.urdf)] == [
        ("r2/base_joint", "r2/base_footprint", "r2/base_link"),
        ("r2/caster_joint", "r2/base_link", "r2/caster"),
    ]
    assert robot.fixed[0].origin == (0.0, 0.0, robot.body.wheel_radius), "base_link at the wheels' axle height"
