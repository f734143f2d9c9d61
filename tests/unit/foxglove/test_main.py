"""The ``blackmetal foxglove`` command: its help says what clients see and may do, and a bad option ends in one sentence."""

from __future__ import annotations

import pytest

from blackmetal.foxglove.main import COMMAND, ONE_ROBOT, build_parser, main


def test_the_help_names_the_layout_the_controls_and_the_fleet_option() -> None:
    text = build_parser().format_help()
    for words in (
        "deploy/foxglove/blackmetal.layout.json",
        "/cmd_vel",
        "set_estop",
        "reset_odometry",
        "--mcap",
        "--fleet",
        "/goal_pose",
        "nav/goal",
    ):
        assert words in " ".join(text.split()), words
    assert COMMAND.name == "foxglove" and COMMAND.fleet is not None and ONE_ROBOT == ""


def test_a_setting_the_view_cannot_use_exits_2_in_one_sentence_before_anything_opens(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", "70000"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == "blackmetal foxglove: --port must be 0..65535, got 70000"
