"""Typed settings (blackmetal.runtime.settings): one precedence, options from the fields, mistakes named where they came from."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import pytest

from blackmetal.runtime.settings import add_setting_arguments, check_positive, default_of, load_settings, read_settings_file, setting
from blackmetal.runtime.zenoh_setup import ZenohSettings
from blackmetal.schemas import ConfigError


@dataclass
class Settings:
    poll_hz: float = setting(50.0, "poll rate (Hz)")
    robot: str = setting("127.0.0.1", "robot address", metavar="HOST")
    mirror_right: bool = setting(True, "the right encoder is mirrored", flag="--no-mirror-right", const=False)
    sources: list[str] = setting(help="command sources", factory=list)
    limit: float | None = setting(None, "an optional limit")
    secret: str = setting("", "not on the command line", cli=False)
    zenoh: ZenohSettings = setting(factory=ZenohSettings, cli=False)

    def check(self) -> None:
        check_positive(self, "poll_hz limit")


def parser() -> argparse.ArgumentParser:
    result = argparse.ArgumentParser(prog="test")
    add_setting_arguments(result, Settings)
    return result


def test_each_field_is_an_option_with_its_help_and_default() -> None:
    text = parser().format_help()
    assert "--poll-hz POLL_HZ poll rate (Hz) (default 50)" in " ".join(text.split())
    assert "--robot HOST" in text and "--no-mirror-right" in text and "--sources VALUE" in text and "--secret" not in text
    assert "--settings FILE" in text
    args = parser().parse_args(["--no-mirror-right", "--sources", "nav", "--sources", "teleop"])
    assert args.mirror_right is False and args.sources == ["nav", "teleop"] and args.poll_hz is None


def test_command_line_beats_environment_beats_file_beats_default(tmp_path: Path) -> None:
    file = tmp_path / "s.toml"
    file.write_text('poll-hz = 20\nrobot = "10.0.0.9"\nsources = ["a"]\nconnect = ["tcp/10.0.0.1:7447"]\n')
    settings = load_settings(
        Settings, {"poll_hz": 100.0, "limit": None}, str(file), environ={"BLACKMETAL_ROBOT": "10.0.0.8", "BLACKMETAL_SOURCES": "b, c"}
    )
    assert (settings.poll_hz, settings.robot, settings.sources, settings.limit) == (100.0, "10.0.0.8", ["b", "c"], None)
    assert settings.mirror_right is True and settings.zenoh.connect == ["tcp/10.0.0.1:7447"]


def test_the_parsed_arguments_name_the_settings_file(tmp_path: Path) -> None:
    file = tmp_path / "s.json5"
    file.write_text("{poll_hz: 25, limit: 2}")
    settings = load_settings(Settings, parser().parse_args(["--settings", str(file)]), environ={})
    assert settings.poll_hz == 25.0 and settings.limit == 2.0


def test_the_environment_may_unset_an_optional_setting() -> None:
    assert load_settings(Settings, {}, environ={"BLACKMETAL_LIMIT": "off"}).limit is None


def test_a_value_of_the_wrong_type_is_named_with_where_it_came_from(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"^--poll-hz: poll_hz must be a number, got 'fast' \(text\)$"):
        load_settings(Settings, {"poll_hz": "fast"}, environ={})
    with pytest.raises(ConfigError, match=r"^BLACKMETAL_POLL_HZ: poll_hz must be a number, got 'fast' \(text\)$"):
        load_settings(Settings, {}, environ={"BLACKMETAL_POLL_HZ": "fast"})
    file = tmp_path / "s.toml"
    file.write_text("robot = 7\n")
    with pytest.raises(ConfigError, match=rf"^settings file {file}: robot must be text, got 7 \(an integer\)$"):
        load_settings(Settings, {}, str(file), environ={})


def test_an_unknown_setting_in_a_file_is_refused_with_the_known_ones(tmp_path: Path) -> None:
    file = tmp_path / "s.toml"
    file.write_text("pol_hz = 20\n")
    with pytest.raises(ConfigError, match=rf"^settings file {file}: unknown settings \['pol_hz'\]; known: \["):
        load_settings(Settings, {}, str(file), environ={})


def test_a_file_that_is_no_table_or_not_there_or_not_valid_is_one_sentence(tmp_path: Path) -> None:
    listed = tmp_path / "s.json5"
    listed.write_text("[1, 2]")
    with pytest.raises(ConfigError, match=r"must hold a table \(TOML\) or an object \(JSON5\) of settings$"):
        read_settings_file(listed)
    with pytest.raises(ConfigError, match=f"^cannot read settings file {tmp_path / 'none.toml'}: "):
        read_settings_file(tmp_path / "none.toml")
    broken = tmp_path / "b.toml"
    broken.write_text("poll_hz = = 2")
    with pytest.raises(ConfigError, match=f"^settings file {broken} is not valid TOML: "):
        read_settings_file(broken)


def test_the_class_check_runs_and_names_the_setting() -> None:
    with pytest.raises(ConfigError, match=r"^limit must be positive, got -1.0$"):
        load_settings(Settings, {"limit": -1.0}, environ={})
    with pytest.raises(ConfigError, match=r"^poll_hz must be positive, got 0.0$"):
        load_settings(Settings, {"poll_hz": 0.0}, environ={})


def test_a_tool_reads_a_services_default() -> None:
    assert default_of(Settings, "poll_hz") == 50.0 and default_of(Settings, "sources") == []
    with pytest.raises(ValueError, match=r"^Settings has no setting 'nope'$"):
        default_of(Settings, "nope")


@dataclass
class Placed:
    where: list[float] = setting(help="x,y,yaw", factory=lambda: [0.0, 0.0, 0.0], metavar="X,Y,YAW", comma=True)


def test_a_comma_list_is_one_option_as_its_variable_is_one_value(tmp_path: Path) -> None:
    """``--where 1,2,0.5`` as ``BLACKMETAL_WHERE=1,2,0.5`` and ``where = [1, 2, 0.5]`` in a file (map_pose's form)."""
    parsed = argparse.ArgumentParser(prog="test")
    add_setting_arguments(parsed, Placed)
    assert "--where X,Y,YAW x,y,yaw (default 0,0,0)" in " ".join(parsed.format_help().split())
    assert load_settings(Placed, parsed.parse_args(["--where=-1, 2,0.5"]), environ={}).where == [-1.0, 2.0, 0.5]
    assert load_settings(Placed, {}, environ={"BLACKMETAL_WHERE": "3,4,0"}).where == [3.0, 4.0, 0.0]
    file = tmp_path / "placed.toml"
    file.write_text("where = [5, 6, 1.5]\n")
    assert load_settings(Placed, {}, settings_file=str(file), environ={}).where == [5.0, 6.0, 1.5]
    assert load_settings(Placed, parsed.parse_args(["--where", "none"]), environ={}).where == []
    with pytest.raises(ConfigError, match=r"--where: where must be a number"):
        load_settings(Placed, parsed.parse_args(["--where", "1,x,2"]), environ={})
