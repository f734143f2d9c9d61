"""The odometry's settings: the pipeline's constants from the options, bad ones refused as configuration errors."""

from __future__ import annotations

import pytest

from blackmetal.odometry_service.params import OdometryParams
from blackmetal.odometry_service.settings import OdometrySettings, PipelineSettings
from blackmetal.robot_model import Encoders
from blackmetal.schemas import ConfigError


def test_the_defaults_are_the_nominal_pipeline_and_options_reach_the_params() -> None:
    assert PipelineSettings().params() == OdometryParams()
    params = PipelineSettings(impulses_left=1000.0, mirror_right=False, max_gap=0.25).params()
    assert params.encoders == Encoders(1000.0, OdometryParams().encoders.impulses_per_meter_right, False)
    assert params.max_gap == 0.25


def test_a_bad_constant_or_prefix_is_a_configuration_error() -> None:
    with pytest.raises(ConfigError, match="filter_alpha must be in"):
        PipelineSettings(filter_alpha=1.0).check()
    with pytest.raises(ConfigError, match="wheel_separation must be positive"):
        OdometrySettings(wheel_separation=0.0).check()
    with pytest.raises(ConfigError):
        OdometrySettings(prefix="a/*").check()
    OdometrySettings(prefix="fleet/a").check()
