"""``blackmetal nav`` / ``python -m blackmetal.nav``: goals in, the robot driven to them, feedback and results out.

Goals come on ``<prefix>/nav/goal`` (and ``move``, ``cancel``); the robot is driven through the gateway's arbiter as the
command source ``nav`` (``<prefix>/cmd_vel/nav``: teleop, locks and the e-stop win over it). It follows the odometry's
pose and the gateway's health, and may start before or after them (docs/navigation.md)."""

from __future__ import annotations

import asyncio

from blackmetal.runtime.edge import refuse_taken
from blackmetal.runtime.entry import ServiceCommand
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.zenoh_setup import open_service_session
from blackmetal.schemas import Keys

from .core import NavCore
from .fleet import FLEET
from .host import NavHost
from .settings import NavSettings
from .zenoh_edge import NavZenoh


async def serve(settings: NavSettings, stop: asyncio.Event) -> None:
    keys = Keys(settings.prefix)
    with await open_service_session(settings.zenoh, stop, "nav") as session:
        refuse_taken(session, "nav", [keys.prefix], what="navigation service")
        edge = NavZenoh(session, keys, command_hz=settings.command_hz)
        core = NavCore(settings.params(), keys, edge.publish, map_pose=settings.start_map_pose(), geofence=settings.fence())
        host = NavHost(core)
        edge.attach(host, asyncio.get_running_loop())
        x, y, yaw = settings.map_pose
        print(
            f"blackmetal nav ready: goals on {keys.nav_goal} -> {keys.cmd_vel_of('nav')}; odom at ({x:g}, {y:g}, {yaw:g} rad) "
            f"on map {settings.map!r}",
            flush=True,
        )
        announce_ready("nav", prefix=settings.prefix)
        try:
            await host.run(stop)
        finally:
            edge.close()


COMMAND = ServiceCommand("nav", NavSettings, __doc__, serve, FLEET)
build_parser, run, main = COMMAND.build_parser, COMMAND.run, COMMAND.main
