"""router: its options, and a configuration it cannot use is one sentence with exit 2."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from blackmetal.tools.router import build_parser, run


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    build_parser(parser)
    return parser.parse_args(list(argv))


def test_the_options() -> None:
    args = _args("-c", "r.json5", "-l", "tcp/0.0.0.0:7447", "-l", "tcp/[::]:7447", "-e", "tcp/10.0.0.1:7447")
    assert (args.config, args.listen, args.connect, args.multicast_scouting) == (
        "r.json5",
        ["tcp/0.0.0.0:7447", "tcp/[::]:7447"],
        ["tcp/10.0.0.1:7447"],
        False,
    )


def test_a_configuration_it_cannot_read_is_one_sentence(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert run(_args("-c", str(tmp_path / "missing.json5"))) == 2
    err = capsys.readouterr().err
    assert err.startswith("blackmetal router: ") and err.count("\n") == 1 and "missing.json5" in err
