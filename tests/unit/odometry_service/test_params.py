"""The odometry's constants (:mod:`blackmetal.odometry_service.params`): the robot's by default, a bad one named.

``check`` is what ``blackmetal odometry`` and ``replay`` run on their
options: its sentence is the one a user reads for a bad value.
"""

from __future__ import annotations

import dataclasses

import pytest

from blackmetal import robot_model as model
from blackmetal.odometry_service.errors import OdometryError
from blackmetal.odometry_service.params import OdometryParams
from blackmetal.robot_model import Encoders


def test_the_defaults_are_the_robots_and_pass_the_check() -> None:
    params = OdometryParams()
    params.check()
    assert (params.wheel_separation, params.max_wheel_speed, params.encoders) == (model.WHEEL_SEPARATION, model.MAX_WHEEL_SPEED, Encoders())
    assert params.spike_limit == pytest.approx(1.05 * model.MAX_WHEEL_SPEED)  # a margin for quantisation, no more


@pytest.mark.parametrize(
    ("change", "sentence"),
    [
        ({"filter_alpha": 1.0}, "filter_alpha must be in [0, 1), got 1.0"),
        ({"filter_alpha": -0.1}, "filter_alpha must be in [0, 1), got -0.1"),
        ({"wheel_separation": 0.0}, "wheel_separation must be positive, got 0.0"),
        ({"encoders": Encoders(impulses_per_meter_left=-1.0)}, "impulses_left must be positive, got -1.0"),
        ({"encoders": Encoders(impulses_per_meter_right=0.0)}, "impulses_right must be positive, got 0.0"),
        ({"max_wheel_speed": -0.8}, "max_wheel_speed must be positive, got -0.8"),
        ({"max_gap": float("nan")}, "max_gap must be positive, got nan"),  # NaN is not positive either
        ({"spike_factor": 0.99}, "spike_factor must be >= 1"),
    ],
)
def test_a_bad_constant_is_refused_by_its_name(change: dict[str, object], sentence: str) -> None:
    with pytest.raises(OdometryError) as refused:
        OdometryParams(**change).check()  # type: ignore[arg-type]
    assert str(refused.value) == sentence


def test_the_boundaries_that_are_allowed() -> None:
    OdometryParams(filter_alpha=0.0, spike_factor=1.0).check()  # no low-pass, no margin


def test_one_record_is_shared_and_cannot_change_under_a_running_pipeline() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        OdometryParams().max_gap = 5.0  # type: ignore[misc]
