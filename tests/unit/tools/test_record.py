"""record: an unusable option is one sentence before anything connects; the default file name."""

from __future__ import annotations

import argparse
import re

import pytest

from blackmetal.tools.record import build_parser, default_name, run


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    build_parser(parser)
    return parser.parse_args(list(argv))


def test_the_default_name_carries_the_date_and_time() -> None:
    assert re.fullmatch(r"blackmetal-\d{8}-\d{6}\.mcap", default_name())


@pytest.mark.parametrize(
    ("argv", "sentence"),
    [
        (("--duration", "0"), "--duration must be positive, got 0.0"),
        (("--split-size", "-1"), "--split-size must be positive (MB), got -1.0"),
    ],
)
def test_a_bad_option_is_one_sentence(argv: tuple[str, ...], sentence: str, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("mcap")
    assert run(_args(*argv)) == 2
    assert capsys.readouterr().err == f"blackmetal record: {sentence}\n"
