"""up --settings: one file split into each service's keys; what up decides itself; the latch's folder."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from blackmetal.schemas import ConfigError
from blackmetal.tools.up.settings import ServiceFiles, latch_args, ros2_extra, split_settings


def test_top_level_keys_go_to_every_service_that_has_them_sections_to_one(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('robot = "10.0.0.2"\npoll_hz = 100\nwatchdog = 8\n[odometry]\nfilter_alpha = 0.2\n')
    own, decided = split_settings(str(path))
    assert own["gateway"] == {"poll_hz": 100} and own["sim"] == {"watchdog": 8} and own["odometry"] == {"filter_alpha": 0.2}
    assert decided == ["robot"]
    path.write_text("bogus = 1\n[gateway]\nfilter_alpha = 0.2\n")
    with pytest.raises(ConfigError, match=r"unknown settings \['bogus', 'gateway.filter_alpha'\]"):
        split_settings(str(path))


def test_each_service_gets_its_own_file_and_one_prefix(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('prefix = "lab/one"\npoll_hz = 100\n')
    files = ServiceFiles(str(path), ["gateway", "sim"])
    try:
        assert files.prefix == "lab/one" and files.args("sim") == []
        (flag, written) = files.args("gateway")
        assert flag == "--settings" and json.loads(Path(written).read_text()) == {"prefix": "lab/one", "poll_hz": 100}
        args = argparse.Namespace(robot=None)
        assert latch_args(args, files) == ["--state-dir", files.run_dir(), "--unsafe-start-released"]
        assert latch_args(argparse.Namespace(robot="10.0.0.2"), files) == []
    finally:
        files.close()
    assert not Path(written).exists()


def test_the_ros2_adapter_gets_the_distro_and_a_calibration_with_residuals(tmp_path: Path) -> None:
    plain = tmp_path / "plain.toml"
    plain.write_text("poll_hz = 100\n")
    assert ros2_extra(argparse.Namespace(distro="humble", settings=str(plain))) == ["--distro", "humble"]
    assert ros2_extra(argparse.Namespace(distro=None, settings=str(tmp_path / "missing.toml"))) == []


def test_the_navigation_takes_its_section_and_the_shared_keys_it_has(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('prefix = "lab/one"\nlinear_accel = 0.8\n[nav]\nmap_pose = [1.0, 2.0, 0.5]\nmax_speed = 0.2\n')
    own, _ = split_settings(str(path))
    assert own["nav"] == {"prefix": "lab/one", "linear_accel": 0.8, "map_pose": [1.0, 2.0, 0.5], "max_speed": 0.2}
    assert own["gateway"] == {"prefix": "lab/one", "linear_accel": 0.8}  # the gateway's limit, and the plan's
    files = ServiceFiles(str(path), ["gateway", "odometry", "nav"])
    try:
        (flag, written) = files.args("nav")
        assert flag == "--settings" and json.loads(Path(written).read_text())["map_pose"] == [1.0, 2.0, 0.5]
    finally:
        files.close()
    path.write_text("[nav]\nmap_pose = [1.0, 2.0]\n")
    with pytest.raises(ConfigError, match="map_pose must be three finite numbers"):
        ServiceFiles(str(path), ["nav"])
