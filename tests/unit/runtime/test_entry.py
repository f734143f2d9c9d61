"""A service's command (blackmetal.runtime.entry): its parser, its exit codes and sentences, its --fleet refusals."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass
from typing import Any

import pytest

from blackmetal.runtime.entry import Fleet, ServiceCommand, loop_factory, say
from blackmetal.runtime.settings import setting
from blackmetal.runtime.zenoh_setup import ZenohSettings
from blackmetal.schemas import ConfigError


@dataclass
class Settings:
    prefix: str = setting("robot", "key prefix")
    poll_hz: float = setting(50.0, "poll rate (Hz)")

    def check(self) -> None:
        if self.poll_hz > 1000:
            raise ConfigError(f"poll_hz {self.poll_hz:g} is beyond 1000 Hz")


async def not_started(settings: Any, stop: asyncio.Event) -> None:
    raise AssertionError("not started")


def command(serve: Any = not_started, fleet: Fleet[Any] | None = None) -> ServiceCommand[Any]:
    return ServiceCommand("test", Settings, "a test service", serve, fleet)


async def fleet_not_started(settings: Any, robots: Any, stop: asyncio.Event) -> None:
    raise AssertionError("not started")


def refusing_fleet() -> Fleet[Any]:
    return Fleet("every robot of FILE", lambda base, robots: [base], fleet_not_started, {"prefix": "each robot has its own"})


def test_the_parser_has_one_option_per_setting_and_the_zenoh_flags_and_fleet_only_when_declared() -> None:
    text = command().build_parser().format_help()
    assert "--prefix PREFIX" in text and "--poll-hz POLL_HZ" in text and "(default 50)" in text
    assert "--connect ENDPOINT" in text and "--settings FILE" in text and "--fleet" not in text
    assert "every robot of FILE" in command(fleet=refusing_fleet()).build_parser().format_help()


def test_one_robot_is_served_with_its_settings_and_exits_0(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BLACKMETAL_EVENT_LOOP", "asyncio")
    served: list[Settings] = []

    async def serve(settings: Settings, stop: asyncio.Event) -> None:
        served.append(settings)

    assert command(serve).main(["--poll-hz", "20", "-e", "tcp/10.0.0.1:7447"]) == 0
    (settings,) = served
    assert settings.poll_hz == 20.0 and settings.prefix == "robot"


def test_a_setting_the_service_cannot_use_exits_2_in_one_sentence(capsys: pytest.CaptureFixture[str]) -> None:
    assert command().main(["--poll-hz", "5000"]) == 2
    assert capsys.readouterr().err == "blackmetal test: poll_hz 5000 is beyond 1000 Hz\n"


def test_what_the_operating_system_refuses_exits_1(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("BLACKMETAL_EVENT_LOOP", "asyncio")

    async def serve(settings: Settings, stop: asyncio.Event) -> None:
        raise OSError("[Errno 98] Address already in use")

    assert command(serve).main([]) == 1
    assert capsys.readouterr().err == "blackmetal test: [Errno 98] Address already in use\n"


def test_a_fleet_option_naming_one_robot_is_refused_in_one_sentence(tmp_path: Any, capsys: pytest.CaptureFixture[str]) -> None:
    assert command(fleet=refusing_fleet()).main(["--fleet", str(tmp_path / "fleet.toml"), "--prefix", "a"]) == 2
    assert capsys.readouterr().err.strip() == (
        "blackmetal test: --prefix is for one robot and cannot be used with --fleet: each robot has its own"
    )


def test_a_fleet_refuses_a_single_robot_setting_from_the_environment_too(
    tmp_path: Any, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("BLACKMETAL_PREFIX", "fleet/x")
    assert command(fleet=refusing_fleet()).main(["--fleet", str(tmp_path / "fleet.toml")]) == 2
    assert capsys.readouterr().err.strip() == (
        "blackmetal test: prefix (from the settings file or BLACKMETAL_PREFIX) is for one robot and cannot be used with --fleet:"
        " each robot has its own"
    )


def test_a_fleet_file_that_cannot_be_read_exits_2_naming_it(tmp_path: Any, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "fleet.toml"
    assert command(fleet=refusing_fleet()).main(["--fleet", str(missing)]) == 2
    assert capsys.readouterr().err.startswith(f"blackmetal test: cannot read fleet file {missing}: ")


def test_the_fleet_serves_every_robot_of_the_file_in_one_process(tmp_path: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BLACKMETAL_EVENT_LOOP", "asyncio")
    fleet_file = tmp_path / "fleet.toml"
    fleet_file.write_text(
        '[[robot]]\nid = "r1"\ncontrol_port = 6651\nlog_port = 6641\n\n[[robot]]\nid = "r2"\ncontrol_port = 6652\nlog_port = 6642\n'
    )
    served: list[list[str]] = []

    async def serve_fleet(base: Settings, robots: list[Any], stop: asyncio.Event) -> None:
        served.append([robot.id for robot in robots])

    fleet = Fleet("every robot of FILE", lambda base, robots: [base for _ in robots], serve_fleet)
    assert command(fleet=fleet).main(["--fleet", str(fleet_file)]) == 0
    assert served == [["r1", "r2"]]


def test_say_prints_each_line_and_leaves_out_none(capsys: pytest.CaptureFixture[str]) -> None:
    say("one", None, "two")
    assert capsys.readouterr().out == "one\ntwo\n"


def test_the_standard_loop_is_chosen_by_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BLACKMETAL_EVENT_LOOP", "asyncio")
    assert loop_factory() is None


def test_the_zenoh_flags_land_in_the_settings_zenoh_field(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BLACKMETAL_EVENT_LOOP", "asyncio")

    @dataclass
    class WithZenoh:
        zenoh: ZenohSettings = setting(factory=ZenohSettings, cli=False)

    served: list[WithZenoh] = []

    async def serve(settings: WithZenoh, stop: asyncio.Event) -> None:
        served.append(settings)

    assert ServiceCommand("test", WithZenoh, None, serve).main(["-e", "tcp/10.0.0.1:7447", "-m", "client"]) == 0
    assert served[0].zenoh.connect == ["tcp/10.0.0.1:7447"] and served[0].zenoh.mode == "client"
