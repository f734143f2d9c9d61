"""``blackmetal gateway --fleet FILE``: each robot's settings from the command line's and its entry."""

from __future__ import annotations

import pytest

from blackmetal.gateway.fleet import FLEET, ROLE, fleet_settings
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.runtime.fleet import FleetRobot
from blackmetal.schemas import ConfigError


def robot(index: int, **tables: dict[str, object]) -> FleetRobot:
    return FleetRobot(index, f"r{index}", "127.0.0.1", 9000 + index, 9100 + index, f"fleet/r{index}", tables=tables)


def test_each_robot_gets_its_link_and_prefix_over_the_command_lines_settings() -> None:
    base = GatewaySettings(poll_hz=20.0)
    first, second = fleet_settings(base, [robot(1), robot(2, gateway={"poll_hz": 10.0})])
    assert (first.control_port, first.log_port, first.prefix, first.poll_hz) == (9001, 9101, "fleet/r1", 20.0)
    assert (second.prefix, second.poll_hz) == ("fleet/r2", 10.0)
    assert (ROLE.service, ROLE.error_key) == ("gateway", "health") and FLEET.help.startswith("serve every robot of this fleet file")


def test_an_unknown_gateway_key_names_the_robot() -> None:
    with pytest.raises(ConfigError, match=r"robot 1 .*unknown gateway setting 'nosuch'"):
        fleet_settings(GatewaySettings(), [robot(1, gateway={"nosuch": 1})])
