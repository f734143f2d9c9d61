"""``blackmetal odometry`` / ``python -m odometry_service``: impulses in, pose out, on Zenoh."""

from __future__ import annotations

import argparse
import asyncio

from blackmetal.runtime.edge import refuse_if_taken
from blackmetal.runtime.entry import run_service, service_parser
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.settings import load_settings
from blackmetal.runtime.zenoh_setup import open_session
from schemas import Keys

from .core import OdometryCore
from .host import OdometryHost
from .settings import OdometrySettings
from .zenoh_edge import OdometryZenoh


async def serve(settings: OdometrySettings, stop: asyncio.Event) -> None:
    """Open the Zenoh session, run the service until ``stop``, close everything."""
    keys = Keys(settings.prefix)
    with open_session(settings.zenoh) as session:
        refuse_if_taken(session, keys.alive_odometry, "odometry service", keys.prefix)
        edge = OdometryZenoh(session, keys)
        host = OdometryHost(OdometryCore(settings.params(), keys, edge))
        handover = edge.attach(host, asyncio.get_running_loop())
        print(f"blackmetal odometry ready: {keys.impulses} -> {keys.pose}", flush=True)
        announce_ready("odometry", prefix=settings.prefix)
        try:
            await host.run(stop, dropped=lambda: handover.stats()["impulses"][1])
        finally:
            edge.close()


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    return service_parser("blackmetal odometry", __doc__, OdometrySettings, parser)


def run(args: argparse.Namespace) -> int:
    return run_service("odometry", lambda: load_settings(OdometrySettings, args), serve)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
