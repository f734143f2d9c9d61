"""up's launch: a dead fleet gateway's robots stopped at once, in one sentence; the status interval."""

from __future__ import annotations

import argparse

import pytest

from blackmetal.runtime.fleet import numbered_fleet
from blackmetal.tools.up import launch


def test_a_fleet_is_stopped_robot_by_robot_and_said_in_one_sentence(monkeypatch: pytest.MonkeyPatch) -> None:
    robots = numbered_fleet(3, first_port=9000)
    reasons = {robots[1].control_port: "cannot connect", robots[2].control_port: "no answer"}
    monkeypatch.setattr(launch, "stop_robot", lambda host, port, timeout: reasons.get(port))
    assert launch._stop_fleet(robots) == "1 of 3 robots were sent zero velocity and NORMAL_STOP; r2: cannot connect (and 1 more)"
    reasons.clear()
    assert launch._stop_fleet(robots) == "3 of 3 robots were sent zero velocity and NORMAL_STOP"


def test_the_status_comes_at_least_every_two_seconds_into_a_file(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("sys.stdout.isatty", lambda: False)
    assert launch._status_interval(argparse.Namespace(status_interval=0.5)) == 2.0
    assert launch._status_interval(argparse.Namespace(status_interval=5.0)) == 5.0


def test_a_navigation_that_dies_is_said_in_one_sentence() -> None:
    """up starts it again, as a gateway: nothing to stop, the gateway's command timeout ends what it drove."""
    assert launch.nav_gone() == "its goals ended; the gateway's command timeout stops a robot it drove"


def test_a_fleets_navigation_is_paced_unless_the_settings_file_says_otherwise(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from blackmetal.tools.up.settings import ServiceFiles

    plain = launch.Launch(argparse.Namespace(), ServiceFiles(None, []), None, [])  # type: ignore[arg-type]
    assert plain.nav_fleet_args == ["--command-hz", "5"] and launch.FLEET_COMMAND_HZ == 5.0
    path = tmp_path / "s.toml"
    path.write_text("[nav]\ncommand_hz = 0\n")
    files = ServiceFiles(str(path), ["nav"])
    try:
        assert files.sets("nav", "command_hz") and not files.sets("gateway", "command_hz")
        assert launch.Launch(argparse.Namespace(), files, None, []).nav_fleet_args == []  # type: ignore[arg-type]
    finally:
        files.close()
