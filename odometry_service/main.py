"""``blackmetal odometry`` / ``python -m blackmetal.odometry_service``: impulses in, pose out, on Zenoh."""

from __future__ import annotations

import asyncio

from blackmetal.runtime.edge import refuse_taken
from blackmetal.runtime.entry import ServiceCommand
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.zenoh_setup import open_service_session
from blackmetal.schemas import Keys

from .core import OdometryCore
from .fleet import FLEET
from .host import OdometryHost
from .settings import OdometrySettings
from .zenoh_edge import OdometryZenoh


async def serve(settings: OdometrySettings, stop: asyncio.Event) -> None:
    keys = Keys(settings.prefix)
    with await open_service_session(settings.zenoh, stop, "odometry") as session:
        refuse_taken(session, "odometry", [keys.prefix], what="odometry service")
        edge = OdometryZenoh(session, keys)
        host = OdometryHost(OdometryCore(settings.params(), keys, edge.publish))
        intake = edge.attach(host, asyncio.get_running_loop())
        print(f"blackmetal odometry ready: {keys.impulses} -> {keys.pose}", flush=True)
        announce_ready("odometry", prefix=settings.prefix)
        try:
            await host.run(stop, dropped=lambda: intake.stats()["impulses"][1])
        finally:
            edge.close()


COMMAND = ServiceCommand("odometry", OdometrySettings, __doc__, serve, FLEET)
build_parser, run, main = COMMAND.build_parser, COMMAND.run, COMMAND.main
