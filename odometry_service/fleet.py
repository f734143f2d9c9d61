"""``blackmetal odometry --fleet FILE``: one process, one Zenoh session, one odometry per robot (docs/fleets.md).

A robot whose handling fails of a bug is reported on its errors key and started again from zero; the others go on.
"""

from __future__ import annotations

import asyncio

from blackmetal.runtime.entry import Fleet
from blackmetal.runtime.fleet import FleetRobot
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.service import Member, Role, serve_fleet
from blackmetal.schemas import Keys

from .core import OdometryCore
from .host import OdometryHost
from .settings import OdometrySettings
from .zenoh_edge import OdometryZenoh

#: How often the fleet's loop takes every robot's waiting impulse samples (s): a pose is at most this much later
#: than a callback would have made it, and the loop wakes 200 times a second for the whole fleet.
DRAIN_PERIOD_S = 0.005


def fleet_settings(base: OdometrySettings, robots: list[FleetRobot]) -> list[OdometrySettings]:
    """Each robot's odometry settings: the command line's, its prefix, its constants and [robot.odometry]."""
    return [robot.settings("odometry", base, {"prefix": robot.prefix}) for robot in robots]


def build(member: Member[OdometrySettings]) -> tuple[OdometryZenoh, OdometryHost]:
    """One robot's odometry, from zero: queries and resets through its intake, impulses from its ring (the fleet's drain)."""
    keys = Keys(member.settings.prefix)
    edge = OdometryZenoh(member.session, keys, burst=member.burst)
    host = OdometryHost(OdometryCore(member.settings.params(), keys, edge.publish))
    edge.attach(host, asyncio.get_running_loop(), ring=True)
    return edge, host


ROLE = Role("odometry", build, "odometry of {robot} failed ({exc!r}): starting again from zero in {pause:g} s", "pose")


async def serve(base: OdometrySettings, robots: list[FleetRobot], stop: asyncio.Event) -> None:
    def announce(members: list[Member[OdometrySettings]]) -> None:
        print(f"blackmetal odometry ready: a fleet of {len(robots)} robots, {Keys(robots[0].prefix).impulses} -> pose, ...", flush=True)
        announce_ready("odometry", prefix=robots[0].prefix, prefixes=[r.prefix for r in robots])

    parts = [(ROLE, robot, s) for robot, s in zip(robots, fleet_settings(base, robots), strict=True)]
    await serve_fleet(base.zenoh, stop, parts, announce, refuse="odometry service", drain_every=(DRAIN_PERIOD_S, None))


FLEET = Fleet("run the odometry of every robot of this fleet file in this one process, on one Zenoh session", fleet_settings, serve)
