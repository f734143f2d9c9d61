"""The bench command: --only and --fleet parsed with one sentence for a bad value, JSON without NaN, exit 2 for bad options."""

from __future__ import annotations

import argparse
import math

import pytest

from blackmetal.bench import _figure_names, _finite, _fleet_sizes, build_parser, run


def test_only_takes_known_figures_and_fleet_whole_sizes() -> None:
    args = build_parser().parse_args(["--only", "cmd_vel, estop", "--fleet"])
    assert args.only == {"cmd_vel", "estop"} and args.fleet == [1, 10, 50, 100]
    with pytest.raises(argparse.ArgumentTypeError, match="unknown figure nope; the figures are forwarder, cmd_vel"):
        _figure_names("nope")
    assert _fleet_sizes("10,1,10") == [1, 10]
    with pytest.raises(argparse.ArgumentTypeError, match="at least 1 robot"):
        _fleet_sizes("0")


def test_json_has_no_nan() -> None:
    assert _finite({"a": [1.0, math.nan], "b": (math.inf, "x")}) == {"a": [1.0, None], "b": [None, "x"]}


def test_bad_options_are_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert run(build_parser().parse_args(["--views"])) == 2
    assert run(build_parser().parse_args(["--json", "/no/such/folder/b.json"])) == 2
    assert capsys.readouterr().err.splitlines() == [
        "blackmetal bench: --views measures the fleet views: give --fleet N as well",
        "blackmetal bench: --json /no/such/folder/b.json: the folder /no/such/folder does not exist",
    ]
