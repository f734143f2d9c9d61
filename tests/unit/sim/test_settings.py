"""The simulator's settings: checks that name the bad value, the faults as one message, when Zenoh is on."""

from __future__ import annotations

import pytest

from blackmetal.schemas import ConfigError, SimFaults
from blackmetal.sim.settings import SimSettings


def test_the_fault_options_make_the_faults_message() -> None:
    SimSettings().check()
    assert SimSettings().faults() == SimFaults()
    assert SimSettings(dropout=0.25, silent=True).faults() == SimFaults(dropout=0.25, silent=True)
    with pytest.raises(ConfigError, match="invalid fault setting"):
        SimSettings(spike=2.0).check()


def test_bad_constants_are_refused_by_name() -> None:
    with pytest.raises(ConfigError, match=r"left_wheel_scale must be within 0.5..2.0, got 3.0"):
        SimSettings(left_wheel_scale=3.0).check()
    with pytest.raises(ConfigError, match="truth_hz"):
        SimSettings(truth_hz=0.0).check()
    with pytest.raises(ConfigError):
        SimSettings(prefix="a/*").check()


def test_zenoh_is_used_when_asked_or_a_prefix_is_given() -> None:
    assert not SimSettings().uses_zenoh
    assert SimSettings(use_zenoh=True).uses_zenoh and SimSettings(prefix="fleet/a").uses_zenoh
