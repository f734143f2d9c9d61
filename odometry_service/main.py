"""``blackmetal odometry`` / ``python -m blackmetal.odometry_service``: impulses in, pose out, on Zenoh."""

from __future__ import annotations

import argparse
import asyncio

from blackmetal.runtime.edge import refuse_taken
from blackmetal.runtime.entry import run_single_or_fleet, service_parser
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.zenoh_setup import open_service_session
from blackmetal.schemas import Keys

from .core import OdometryCore
from .fleet import fleet_settings, serve_fleet
from .host import OdometryHost
from .settings import OdometrySettings
from .zenoh_edge import OdometryZenoh


async def serve(settings: OdometrySettings, stop: asyncio.Event) -> None:
    """Open the Zenoh session, run the service until ``stop``, close everything."""
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


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = service_parser("blackmetal odometry", __doc__, OdometrySettings, parser)
    parser.add_argument(
        "--fleet", metavar="FILE", help="run the odometry of every robot of this fleet file in this one process, on one Zenoh session"
    )
    return parser


def run(args: argparse.Namespace) -> int:
    return run_single_or_fleet("odometry", args, OdometrySettings, serve, fleet_settings, serve_fleet)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
