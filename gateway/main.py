"""``blackmetal gateway`` / ``python -m gateway``: the robot's Zenoh gateway."""

from __future__ import annotations

import argparse
import asyncio
import sys

from blackmetal.runtime.edge import refuse_if_taken
from blackmetal.runtime.entry import run_service, service_parser
from blackmetal.runtime.fleet import FleetRobot, load_fleet
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.settings import load_settings
from blackmetal.runtime.zenoh_setup import open_service_session
from blackmetal.transport import TcpConnector
from schemas import Keys

from .fleet import fleet_settings, serve_fleet
from .host import GatewayHost
from .settings import GatewaySettings
from .zenoh_edge import GatewayZenoh

#: Zenoh delivers samples on its own threads; a short GIL switch interval lets
#: them hand a command over without waiting out the default 5 ms slice.
SWITCH_INTERVAL_S = 0.0005


async def serve(settings: GatewaySettings, stop: asyncio.Event) -> None:
    """Open the Zenoh session, run the service until ``stop``, close everything."""
    connector = TcpConnector(settings.robot, settings.control_port, settings.log_port, settings.connect_timeout)
    keys = Keys(settings.prefix)
    with await open_service_session(settings.zenoh, stop, "gateway") as session:
        refuse_if_taken(session, keys.alive_gateway, "gateway", keys.prefix)
        edge = GatewayZenoh(session, keys)
        service = GatewayHost(settings, connector, edge)
        edge.attach(service, asyncio.get_running_loop())
        print(
            f"blackmetal gateway ready: robot {settings.robot}:{settings.control_port} (log {settings.log_port}), "
            f"prefix {settings.prefix}, polling at {settings.poll_hz:g} Hz",
            flush=True,
        )
        announce_ready("gateway", prefix=settings.prefix, cmd_timeout=settings.cmd_timeout)
        try:
            await service.run(stop)
        finally:
            edge.close()


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = service_parser("blackmetal gateway", __doc__, GatewaySettings, parser)
    parser.add_argument(
        "--fleet",
        metavar="FILE",
        help="serve every robot of this fleet file (TOML [[robot]] tables) in this one process, on one Zenoh session; "
        "the other options are every robot's defaults",
    )
    return parser


def run(args: argparse.Namespace) -> int:
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    if getattr(args, "fleet", None):

        def load_fleet_settings() -> tuple[GatewaySettings, list[FleetRobot]]:
            base = load_settings(GatewaySettings, args)
            robots = load_fleet(args.fleet)
            fleet_settings(base, robots)  # every robot's settings checked before Zenoh is opened
            return base, robots

        return run_service("gateway", load_fleet_settings, lambda loaded, stop: serve_fleet(*loaded, stop))
    return run_service("gateway", lambda: load_settings(GatewaySettings, args), serve)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
