"""What a ROS 2 core is given (:mod:`blackmetal.ros2.options`): its defaults agree with the command's and the gateway's.

A core built from ``Ros2Options`` alone (as tests and the fleet build one)
must behave as the ``blackmetal ros2`` command does with no option given,
and hold the robot link against the poll rate the gateway runs at by default.
"""

from __future__ import annotations

import dataclasses

from blackmetal.gateway.arbiter import DEFAULT_SOURCES
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.robot_model import Encoders
from blackmetal.ros2.options import Ros2Options
from blackmetal.ros2.ros_types import Frames
from blackmetal.ros2.settings import Ros2Settings
from blackmetal.schemas import Keys

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
