"""``blackmetal gateway --fleet FILE``: one process and Zenoh session, one supervised robot per entry (docs/fleets.md).

A robot's failure stays its own: its host is stopped (the robot left standing), reported and started again.
"""

from __future__ import annotations

import asyncio
import os
from typing import Any

from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.entry import Fleet, freeze_start_up, say
from blackmetal.runtime.fleet import FleetRobot
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.service import Member, Role, serve_fleet
from blackmetal.schemas import Keys
from blackmetal.transport import TcpConnector

from .host import GatewayHost
from .settings import GatewaySettings, when_killed
from .zenoh_edge import GatewayZenoh


def fleet_settings(base: GatewaySettings, robots: list[FleetRobot]) -> list[GatewaySettings]:
    """Each robot's gateway settings: the command line's, its link and prefix, its constants and [robot.gateway]."""
    return [
        robot.settings(
            "gateway", base, {"robot": robot.host, "control_port": robot.control_port, "log_port": robot.log_port, "prefix": robot.prefix}
        )
        for robot in robots
    ]


def build(session: Any, s: GatewaySettings, burst: PutBurst | None = None) -> tuple[GatewayZenoh, GatewayHost]:
    """One robot's edge and host; in a fleet, its impulses in the fleet's ``burst``."""
    edge = GatewayZenoh(session, Keys(s.prefix), burst=burst)
    host = GatewayHost(s, TcpConnector(s.robot, s.control_port, s.log_port, s.connect_timeout), edge.publish, s.latch_store())
    edge.attach(host, asyncio.get_running_loop())
    return edge, host


ROLE: Role[GatewaySettings] = Role(
    "gateway",
    lambda m: build(m.session, m.settings, m.burst),
    "gateway of {robot} failed ({exc!r}): the robot was stopped; starting again in {pause:g} s",
    "health",
)


async def serve(base: GatewaySettings, robots: list[FleetRobot], stop: asyncio.Event) -> None:
    """Open one Zenoh session and serve every robot of the fleet on it until ``stop``."""

    def announce(members: list[Member[GatewaySettings]]) -> None:
        freeze_start_up()
        say(
            f"blackmetal gateway ready: a fleet of {len(members)} robots ({', '.join(r.prefix for r in robots[:3])}"
            f"{', ...' if len(robots) > 3 else ''}), polling at {base.poll_hz:g} Hz",
            f"  {when_killed('HOST')} for each robot",
            f"  e-stop states kept in {os.path.dirname(members[0].host.latch.where)}",
            *(f"  {m.robot.id}: {m.host.start_sentence}" for m in members if m.host.start_sentence is not None),
        )
        announce_ready(
            "gateway", prefix=robots[0].prefix, prefixes=[r.prefix for r in robots], cmd_timeout=base.cmd_timeout, poll_hz=base.poll_hz
        )

    parts = [(ROLE, robot, s) for robot, s in zip(robots, fleet_settings(base, robots), strict=True)]
    await serve_fleet(base.zenoh, stop, parts, announce, refuse="gateway")


FLEET = Fleet(
    "serve every robot of this fleet file (TOML [[robot]] tables) in this one process, on one Zenoh session; "
    "the other options are every robot's defaults",
    fleet_settings,
    serve,
)
