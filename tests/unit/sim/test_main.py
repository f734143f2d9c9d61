"""``blackmetal sim``: its fleet options, and a fleet started on free ports whose fleet file the other services read."""

from __future__ import annotations

import asyncio

import pytest

from blackmetal.runtime.fleet import load_fleet, numbered_fleet
from blackmetal.sim.main import build_parser, serve, serve_fleet
from blackmetal.sim.settings import SimSettings


def test_robots_and_a_fleet_file_exclude_each_other() -> None:
    args = build_parser().parse_args(["--robots", "3", "--write-fleet", "fleet.toml", "--dropout", "0.1"])
    assert (args.robots, args.fleet, args.write_fleet, args.dropout) == (3, None, "fleet.toml", 0.1)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--robots", "3", "--fleet", "fleet.toml"])


def test_a_fleet_binds_free_ports_and_writes_them_to_its_fleet_file(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    fleet_file = tmp_path / "fleet.toml"
    stop = asyncio.Event()
    stop.set()  # announce, then close at once
    base = SimSettings(control_port=0, log_port=0)
    asyncio.run(serve_fleet(base, numbered_fleet(2), stop, str(fleet_file)))
    robots = load_fleet(fleet_file)
    assert [r.prefix for r in robots] == ["fleet/r1", "fleet/r2"]
    assert all(r.control_port and r.log_port for r in robots) and robots[0].control_port != robots[1].control_port
    assert f"a fleet of 2 robots on ports {robots[0].control_port}/{robots[0].log_port}" in capsys.readouterr().out


def test_one_robot_announces_its_ports_without_zenoh(capsys) -> None:  # type: ignore[no-untyped-def]
    stop = asyncio.Event()
    stop.set()
    asyncio.run(serve(SimSettings(control_port=0, log_port=0), stop))
    line = capsys.readouterr().out.splitlines()[0]
    assert line.startswith("blackmetal sim ready: control 127.0.0.1:") and "truth" not in line
