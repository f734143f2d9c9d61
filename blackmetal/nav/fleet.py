"""``blackmetal nav --fleet FILE``: one process, one Zenoh session, one navigation per robot (docs/navigation.md).

Each robot's ``[robot.nav]`` table gives it its own settings (``map_pose = [x, y, yaw]``, ``geofence``, limits). A
robot whose handling fails of a bug is reported on its errors key and started again from zero, its goal ended; the
others go on.
"""

from __future__ import annotations

import asyncio

from blackmetal.runtime.entry import Fleet
from blackmetal.runtime.fleet import FleetRobot
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.service import Member, Role, serve_fleet
from blackmetal.schemas import Keys

from .core import NavCore
from .host import NavHost
from .settings import NavSettings
from .zenoh_edge import NavZenoh

#: How often the fleet's loop takes every robot's newest pose (s): a command follows its pose at most this much later,
#: and the loop wakes 100 times a second for the whole fleet, not once per pose.
DRAIN_PERIOD_S = 0.01


def fleet_settings(base: NavSettings, robots: list[FleetRobot]) -> list[NavSettings]:
    """Each robot's navigation settings: the command line's, its prefix, then its [robot.nav] table."""
    return [robot.settings("nav", base, {"prefix": robot.prefix}) for robot in robots]


def build(member: Member[NavSettings]) -> tuple[NavZenoh, NavHost]:
    """One robot's navigation, from zero: inputs and queries through its intake, poses from its ring (the fleet's drain)."""
    settings = member.settings
    keys = Keys(settings.prefix)
    edge = NavZenoh(member.session, keys, burst=member.burst, command_hz=settings.command_hz)
    core = NavCore(settings.params(), keys, edge.publish, map_pose=settings.start_map_pose(), geofence=settings.fence())
    host = NavHost(core, supervised=True)
    edge.attach(host, asyncio.get_running_loop(), ring=True)
    return edge, host


ROLE = Role("nav", build, "navigation of {robot} failed ({exc!r}): its goal ended, starting again from zero in {pause:g} s")


async def serve(base: NavSettings, robots: list[FleetRobot], stop: asyncio.Event) -> None:
    def announce(members: list[Member[NavSettings]]) -> None:
        print(f"blackmetal nav ready: a fleet of {len(robots)} robots, goals on {Keys(robots[0].prefix).nav_goal}, ...", flush=True)
        announce_ready("nav", prefix=robots[0].prefix, prefixes=[r.prefix for r in robots])

    parts = [(ROLE, robot, s) for robot, s in zip(robots, fleet_settings(base, robots), strict=True)]
    await serve_fleet(base.zenoh, stop, parts, announce, refuse="navigation service", drain_every=(DRAIN_PERIOD_S, None))


FLEET = Fleet(
    "navigate every robot of this fleet file in this one process, on one Zenoh session (each robot's map_pose in its "
    "[robot.nav] table); not with --prefix, --map-pose",
    fleet_settings,
    serve,
    single_robot={
        "prefix": "each robot has its own (fleet/<id>)",
        "map_pose": "each robot's odometry sits elsewhere on the map: map_pose = [x, y, yaw] in its [robot.nav] table",
    },
)
