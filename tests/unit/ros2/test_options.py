"""What a ROS 2 core is given (:mod:`blackmetal.ros2.options`): its defaults agree with the command's and the gateway's;
the wheels as joints, angles integrated from the impulses, and their transforms.

A core built from ``Ros2Options`` alone (as tests and the fleet build one)
must behave as the ``blackmetal ros2`` command does with no option given,
and hold the robot link against the poll rate the gateway runs at by default.
For the wheels, encoders of 100 impulses per metre and a 0.1 m radius make the
numbers plain: 10 impulses/s is 0.1 m/s, 1 rad/s of the wheel.
"""

from __future__ import annotations

import dataclasses
import math

import pytest

from blackmetal.gateway.arbiter import DEFAULT_SOURCES
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.robot_model import MAX_JOINT_GAP_S, Encoders, WheelAngles
from blackmetal.ros2.options import Ros2Options, Wheel
from blackmetal.ros2.ros_types import Frames
from blackmetal.ros2.settings import Ros2Settings
from blackmetal.schemas import Keys, WheelImpulses

MINIMAL = Ros2Options(Frames(), [0.0] * 36, [0.0] * 36, False, ("l", "r"), 0.1, Encoders())
#: Options whose default is the node's own, not the command's: the keys the command names after its edge's.
NAMED_BY_THE_EDGE = {"data_keys", "service_keys", "robot"}


def test_the_defaults_are_the_commands_defaults() -> None:
    command = Ros2Settings().options({"cmd_vel": "c", "estop": "e"})
    for option in dataclasses.fields(Ros2Options):
        if option.default is not dataclasses.MISSING and option.name not in NAMED_BY_THE_EDGE:
            assert getattr(MINIMAL, option.name) == getattr(command, option.name), option.name


def test_the_robot_link_is_held_against_the_gateways_default_poll_rate() -> None:
    assert MINIMAL.expected_poll_hz == GatewaySettings().poll_hz


def test_ros_commands_drive_as_a_source_the_gateway_knows_by_default() -> None:
    assert Keys("r1").cmd_vel_of(MINIMAL.source) == "r1/cmd_vel/ros2"
    assert MINIMAL.source in {spec.name for spec in DEFAULT_SOURCES}  # else a ROS command would be refused as unknown


MIRRORED = Encoders(impulses_per_meter_left=100.0, impulses_per_meter_right=100.0, mirror_right=True)


def sample(stamp: float, left: int, right: int, mono: float | None = None) -> WheelImpulses:
    return WheelImpulses(seq=0, stamp=stamp, left=left, right=right, mono=mono)


def joints() -> WheelAngles:
    return WheelAngles()


def test_the_angles_are_the_trapezoid_of_the_wheel_speeds_forward_positive() -> None:
    wheels = joints()
    wheels.feed(sample(10.0, 0, 0), MIRRORED, 0.1)  # the first sample: nothing to integrate yet
    assert wheels.positions == [0.0, 0.0]
    wheels.feed(sample(10.2, 10, -20), MIRRORED, 0.1)  # the right encoder counts backwards when the wheel turns forward
    assert wheels.velocities == [pytest.approx(1.0), pytest.approx(2.0)]
    assert wheels.positions == [pytest.approx(0.1), pytest.approx(0.2)]  # (0 + 1) / 2 * 0.2, (0 + 2) / 2 * 0.2
    wheels.feed(sample(10.4, 10, 20), MIRRORED, 0.1)  # the right wheel reverses: its angle comes back through zero speed
    assert wheels.positions == [pytest.approx(0.3), pytest.approx(0.2)]
    assert wheels.velocities == [pytest.approx(1.0), pytest.approx(-2.0)]


def test_a_gap_a_repeat_or_a_step_back_in_time_turns_no_wheel_but_updates_the_speeds() -> None:
    wheels = joints()
    wheels.feed(sample(0.0, 10, -10), MIRRORED, 0.1)
    wheels.feed(sample(MAX_JOINT_GAP_S + 0.01, 10, -10), MIRRORED, 0.1)  # a lost link is not motion
    wheels.feed(sample(MAX_JOINT_GAP_S + 0.01, 10, -10), MIRRORED, 0.1)  # the same time again
    wheels.feed(sample(0.2, 30, -30), MIRRORED, 0.1)  # out of order
    assert wheels.positions == [0.0, 0.0] and wheels.velocities == [pytest.approx(3.0), pytest.approx(3.0)]
    wheels.feed(sample(0.2 + MAX_JOINT_GAP_S, 30, -30), MIRRORED, 0.1)  # exactly the longest gap still integrates
    assert wheels.positions == [pytest.approx(3.0 * MAX_JOINT_GAP_S)] * 2


def test_the_robots_monotonic_time_is_used_over_the_wall_clock_stamp() -> None:
    wheels = joints()
    wheels.feed(sample(100.0, 10, -10, mono=5.0), MIRRORED, 0.1)
    wheels.feed(sample(50.0, 10, -10, mono=5.1), MIRRORED, 0.1)  # the wall clock stepped back; the robot's time went on 0.1 s
    assert wheels.positions == [pytest.approx(0.1), pytest.approx(0.1)]


@pytest.mark.parametrize(("angle", "rotation"), [(0.0, (0.0, 0.0, 0.0, 1.0)), (math.pi, (0.0, 1.0, 0.0, 0.0))])
def test_a_wheels_transform_turns_about_its_axle_at_its_offset(angle: float, rotation: tuple[float, ...]) -> None:
    transform = Wheel("base_link", "left_wheel", 0.15).transform(angle)
    assert (transform.parent, transform.child, transform.translation) == ("base_link", "left_wheel", (0.0, 0.15, 0.0))
    assert transform.rotation == pytest.approx(rotation)
    x, y, z, w = Wheel("base_link", "left_wheel", 0.15).transform(1.0).rotation
    assert (x, z) == (0.0, 0.0) and 2 * math.atan2(y, w) == pytest.approx(1.0)  # the angle about +y, unit quaternion
