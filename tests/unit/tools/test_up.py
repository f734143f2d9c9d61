"""up's command line: its options and the one sentence for a fleet option that makes no sense."""

from __future__ import annotations

import argparse

import pytest

from blackmetal.tools.up import build_parser, run


def _args(*argv: str) -> argparse.Namespace:
    return build_parser().parse_args(list(argv))


def test_the_defaults_simulate_one_robot_and_no_views() -> None:
    args = _args()
    assert args.robot is None and args.robots is None and args.ros2 is None and not args.foxglove
    assert args.status_interval == 0.5


@pytest.mark.parametrize(
    ("argv", "sentence"),
    [
        (("--robots", "0"), "--robots needs at least 1 robot, got 0"),
        (("--robots", "3", "--prefix", "x"), "--prefix does not go with --robots"),
        (("--robots", "3", "--processes", "4"), "--processes 4: give 1 to 3"),
    ],
)
def test_a_fleet_option_that_makes_no_sense_is_one_sentence(
    argv: tuple[str, ...], sentence: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run(_args(*argv, "-l", "tcp/127.0.0.1:1")) == 2
    err = capsys.readouterr().err
    assert err.startswith("blackmetal up: ") and sentence in err and err.count("\n") == 1
