"""The navigation's settings: map_pose as X,Y,YAW or [x, y, yaw] from every source, the geofence, the live
parameters' start values, and every mistake refused in one sentence."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from blackmetal.nav.main import build_parser
from blackmetal.nav.params import NavParams
from blackmetal.nav.settings import NavSettings
from blackmetal.runtime.fleet import parse_fleet
from blackmetal.runtime.settings import load_settings
from blackmetal.schemas import ConfigError


def load(*argv: str, environ: dict[str, str] | None = None) -> NavSettings:
    return load_settings(NavSettings, build_parser().parse_args(list(argv)), environ=environ or {})


def test_the_defaults_are_navparams_and_the_map_sits_on_the_odometry() -> None:
    settings = load()
    assert settings.params() == NavParams()
    assert settings.prefix == "robot" and settings.map == "map" and settings.fence() is None
    placed = settings.start_map_pose(wallclock=12.5)
    assert (placed.stamp, placed.x, placed.y, placed.yaw, placed.map, placed.by) == (12.5, 0.0, 0.0, 0.0, "map", "settings")


def test_every_live_parameter_is_a_setting_of_its_name() -> None:
    names = {f.name for f in dataclasses.fields(NavSettings)}
    assert {f.name for f in dataclasses.fields(NavParams)} <= names
    settings = load("--max-speed", "0.2", "--yaw-tolerance", "0.03", "--feedback-hz", "20")
    assert (settings.params().max_speed, settings.params().yaw_tolerance, settings.params().feedback_hz) == (0.2, 0.03, 20.0)


def test_command_hz_is_off_unless_asked() -> None:
    assert load().command_hz == 0.0 and load("--command-hz", "10").command_hz == 10.0


def test_map_pose_and_geofence_from_the_command_line_the_environment_and_a_file(tmp_path: Path) -> None:
    settings = load("--map-pose=-1.5,2,1.57", "--map", "floor2", "--geofence=-5,-4,5,4")
    assert settings.map_pose == [-1.5, 2.0, 1.57] and settings.fence() == (-5.0, -4.0, 5.0, 4.0)
    assert settings.start_map_pose().map == "floor2" and settings.start_map_pose().x == -1.5
    assert load(environ={"BLACKMETAL_MAP_POSE": "3,4,0.5"}).map_pose == [3.0, 4.0, 0.5]
    file = tmp_path / "nav.toml"
    file.write_text('map_pose = [1, 2, 3]\ngeofence = [0, 0, 10, 10]\nprefix = "fleet/a"\n')
    from_file = load("--settings", str(file))
    assert (from_file.map_pose, from_file.fence(), from_file.prefix) == ([1.0, 2.0, 3.0], (0.0, 0.0, 10.0, 10.0), "fleet/a")


def test_a_fleet_files_robot_nav_table_places_each_robot() -> None:
    robots = parse_fleet(
        {
            "robot": [
                {"id": "r1", "control_port": 1, "log_port": 2, "nav": {"map_pose": [10, 0, math.pi], "max_speed": 0.2}},
                {"id": "r2", "control_port": 3, "log_port": 4},
            ]
        }
    )
    first, second = (robot.settings("nav", NavSettings(), {"prefix": robot.prefix}) for robot in robots)
    assert first.map_pose == [10.0, 0.0, math.pi] and first.params().max_speed == 0.2 and first.prefix == "fleet/r1"
    assert second.map_pose == [0.0, 0.0, 0.0] and second.prefix == "fleet/r2"
    bad = parse_fleet({"robot": [{"id": "r1", "control_port": 1, "log_port": 2, "nav": {"map_pose": [1, 2]}}]})
    with pytest.raises(ConfigError, match=r"robot 1 \(id 'r1'\): map_pose must be three finite numbers"):
        bad[0].settings("nav", NavSettings(), {"prefix": bad[0].prefix})
    unknown = parse_fleet({"robot": [{"id": "r1", "control_port": 1, "log_port": 2, "nav": {"speed": 1}}]})
    with pytest.raises(ConfigError, match=r"unknown nav setting 'speed' in \[robot.nav\]"):
        unknown[0].settings("nav", NavSettings(), {"prefix": unknown[0].prefix})


@pytest.mark.parametrize(
    ("argv", "sentence"),
    [
        (["--map-pose", "1,2"], r"map_pose must be three finite numbers X,Y,YAW \(m, m, rad\), got \[1.0, 2.0\]"),
        (["--map-pose", "1,nan,0"], r"map_pose must be three finite numbers"),
        (["--map-pose", "1,north,0"], r"--map-pose: map_pose must be a number"),
        (["--geofence", "0,0,1"], r"geofence must be four finite numbers XMIN,YMIN,XMAX,YMAX"),
        (["--geofence", "5,0,1,10"], r"XMIN must be below XMAX and YMIN below YMAX"),
        (["--max-speed", "0"], r"nav setting max_speed must be within .*, got 0.0"),
        (["--pose-timeout", "-1"], r"nav setting pose_timeout must be within .*, got -1.0"),
        (["--feedback-hz", "2"], r"nav setting feedback_hz must be within .*, got 2.0"),
        (["--map", " "], r"map must name the site map"),
        (["--command-hz", "-1"], r"command_hz must be from 0 \(one command per pose\) to 1000, got -1"),
        (["--prefix", "robot/*"], r"prefix 'robot/\*' must not contain wildcards"),
    ],
)
def test_a_setting_it_cannot_use_is_one_sentence(argv: list[str], sentence: str) -> None:
    with pytest.raises(ConfigError, match=sentence):
        load(*argv)
