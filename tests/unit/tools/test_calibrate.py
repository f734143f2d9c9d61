"""calibrate: end points, the settings file it writes, and the runs a recording's metadata marks."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from blackmetal.odometry_service.batch import BatchResult
from blackmetal.odometry_service.calibration import Constants, ResidualFigures
from blackmetal.runtime.settings import read_settings_file
from blackmetal.schemas import ConfigError
from blackmetal.tools.calibrate import _runs, as_residuals, parse_point, write_toml


def test_an_end_point_is_two_finite_numbers() -> None:
    assert parse_point("0.012,-0.034") == (0.012, -0.034)
    with pytest.raises(ConfigError, match="DX,DY in metres"):
        parse_point("0.012")
    with pytest.raises(ConfigError, match="finite"):
        parse_point("nan,0")


def test_the_written_file_is_a_settings_file_with_the_residuals_as_comments(tmp_path: Path) -> None:
    figures = ResidualFigures(x_m=0.01, y_m=0.02, yaw_rad=0.03, v_mps=0.04, w_radps=0.05, path_m=2.0, steps=100)
    residuals = as_residuals(figures)
    assert residuals is not None
    path = tmp_path / "calibration.toml"
    write_toml(str(path), Constants(1000.5, 1001.25, 0.3051), "a note", residuals)
    text = path.read_text()
    assert text.startswith("# a note\n# For blackmetal gateway, blackmetal odometry and blackmetal up: --settings calibration.toml\n")
    assert read_settings_file(str(path)) == {"wheel_separation": 0.3051, "impulses_left": 1000.5, "impulses_right": 1001.25}
    assert as_residuals(ResidualFigures(x_m=0, y_m=0, yaw_rad=0, v_mps=math.nan, w_radps=0, path_m=0, steps=0)) is None
    with pytest.raises(ConfigError, match="cannot write"):
        write_toml(str(tmp_path / "no" / "such.toml"), Constants(1.0, 1.0, 1.0), "x")


def _result(yaw: np.ndarray) -> BatchResult:
    n = len(yaw)
    zeros = np.zeros(n)
    return BatchResult(stamp=np.arange(n, dtype=float), x=zeros, y=zeros, yaw=yaw, v=zeros, w=zeros)


def test_runs_are_the_marked_squares_else_the_whole_recording() -> None:
    result = _result(np.linspace(0.0, 1.0, 100))  # turning left all along
    spans = [("blackmetal.square", {"start_ns": "10e9", "end_ns": "40e9", "size_m": "1.0", "direction": "clockwise"}),
             ("blackmetal.square", {"start_ns": "50e9", "end_ns": "90e9", "size_m": "1.0"}),
             ("blackmetal.square", {"start_ns": "oops"}), ("other", {})]  # fmt: skip
    runs = _runs("r.mcap", result, spans)
    assert [(r.start, r.end, r.direction, r.side) for r in runs] == [(10, 40, "clockwise", 1.0), (50, 90, "counter-clockwise", 1.0)]
    (whole,) = _runs("r.jsonl", _result(np.linspace(0.0, -1.0, 100)), [])
    assert (whole.start, whole.end, whole.direction, whole.side) == (0, 100, "clockwise", None)
