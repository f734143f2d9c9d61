"""The ``blackmetal ros2`` command (:mod:`blackmetal.ros2.main`): its help, and a bad option in one sentence."""

from __future__ import annotations

import pytest

from blackmetal.ros2.main import COMMAND, build_parser, main


def test_the_help_names_the_topics_services_flavors_and_fleet() -> None:
    text = " ".join(build_parser().format_help().split())
    for words in ("/cmd_vel", "set_estop", "reset_odometry", "--flavor", "--distro", "--fleet", "--no-robot-model", "rmw_zenoh"):
        assert words in text, words
    assert COMMAND.name == "ros2" and COMMAND.fleet is not None


@pytest.mark.parametrize(
    ("argv", "line"),
    [
        (["--distro", "foxy"], "blackmetal ros2: --distro 'foxy' is not a ROS 2 distro"),
        (["--node-name", "9lives"], "blackmetal ros2: node name '9lives' is not a valid ROS name"),
    ],
)
def test_a_setting_the_node_cannot_use_exits_2_in_one_sentence(argv: list[str], line: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    (err,) = capsys.readouterr().err.strip().splitlines()
    assert err.startswith(line)
