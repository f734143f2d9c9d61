"""``blackmetal gateway``: its command line comes from the settings, with ``--fleet``."""

from __future__ import annotations

from blackmetal.gateway.main import COMMAND, build_parser
from blackmetal.gateway.settings import GatewaySettings


def test_the_command_line_has_every_setting_and_the_fleet_option() -> None:
    args = build_parser().parse_args(["--robot", "10.0.0.5", "--poll-hz", "20", "--fleet", "fleet.toml"])
    assert (args.robot, args.poll_hz, args.fleet) == ("10.0.0.5", 20.0, "fleet.toml")
    assert COMMAND.name == "gateway" and COMMAND.settings is GatewaySettings
