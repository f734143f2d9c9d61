"""The gateway's settings: what they refuse, naming the setting, and the parts they build."""

from __future__ import annotations

import pytest

from blackmetal import robot_model as model
from blackmetal.gateway.arbiter import DEFAULT_SOURCES
from blackmetal.gateway.settings import SAFETY_SETTINGS, GatewaySettings, when_killed
from blackmetal.schemas import ConfigError


@pytest.mark.parametrize(
    ("changes", "says"),
    [
        ({"poll_hz": 0.0}, "poll_hz"),
        ({"poll_hz": 2000.0}, "beyond 1000 Hz"),
        ({"max_wheel_speed": 1.5}, "wire limit of 1.0 m/s"),
        ({"keepalive": 10.0}, "shorter than the robot's 10 s watchdog"),
        ({"cmd_timeout": -1.0}, "cmd_timeout must be >= 0"),
        ({"cmd_timeout": 61.0}, "a deadman that waits longer than a minute"),
        ({"control_port": 0}, "control_port must be a TCP port"),
        ({"impulses_left": 1.0}, "is the calibration right?"),
        ({"source": []}, "at least one command source"),
        ({"lock": ["a b:3"]}, "one key chunk"),
        ({"position_speed": 0.0}, "position_speed"),
        ({"position_speed": 1.2}, "position_speed 1.2 is beyond the robot's wire limit"),
        ({"position_moves": True, "max_wheel_speed": 0.2}, "every position move would be refused"),
    ],
)
def test_settings_that_cannot_work_are_refused_naming_the_setting(changes: dict[str, object], says: str) -> None:
    with pytest.raises(ConfigError) as error:
        GatewaySettings(**changes).check()  # type: ignore[arg-type]
    assert says in str(error.value)


def test_the_defaults_work_and_give_the_default_sources() -> None:
    settings = GatewaySettings()
    settings.check()
    assert settings.arbiter().sources == DEFAULT_SOURCES
    assert "blackmetal stop-robot --robot 10.0.0.5" in when_killed("10.0.0.5")


def test_the_safety_settings_carry_the_same_named_ones_and_each_wheels_gain() -> None:
    settings = GatewaySettings(max_wheel_speed=0.5, impulses_left=2 * model.IMPULSES_PER_METER_LEFT)
    safety = settings.safety()
    assert all(getattr(safety, name) == getattr(settings, name) for name in SAFETY_SETTINGS)
    assert safety.wheel_gain.left == pytest.approx(2.0) and safety.wheel_gain.right == pytest.approx(1.0)


def test_the_latch_is_kept_per_prefix_under_the_state_dir(tmp_path: object) -> None:
    store = GatewaySettings(state_dir=str(tmp_path), prefix="fleet/r3").latch_store()
    assert store.where == f"{tmp_path}/estop/fleet%2Fr3.json"
