"""``blackmetal gateway`` / ``python -m blackmetal.gateway``: the robot's Zenoh gateway."""

from __future__ import annotations

import argparse
import asyncio
import sys

from blackmetal.runtime.edge import refuse_taken
from blackmetal.runtime.entry import freeze_start_up, run_single_or_fleet, service_parser
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.zenoh_setup import open_service_session
from blackmetal.schemas import Keys
from blackmetal.transport import TcpConnector

from .fleet import fleet_settings, serve_fleet
from .host import GatewayHost
from .settings import GatewaySettings, when_killed
from .zenoh_edge import GatewayZenoh

#: Zenoh delivers samples on its own threads; a short GIL switch interval lets
#: them hand a command over without waiting out the default 5 ms slice.
SWITCH_INTERVAL_S = 0.0005


async def serve(settings: GatewaySettings, stop: asyncio.Event) -> None:
    """Open the Zenoh session, run the service until ``stop``, close everything."""
    connector = TcpConnector(settings.robot, settings.control_port, settings.log_port, settings.connect_timeout)
    keys = Keys(settings.prefix)
    with await open_service_session(settings.zenoh, stop, "gateway") as session:
        refuse_taken(session, "gateway", [keys.prefix])
        edge = GatewayZenoh(session, keys)
        service = GatewayHost(settings, connector, edge.publish, settings.latch_store())
        edge.attach(service, asyncio.get_running_loop())
        print(
            f"blackmetal gateway ready: robot {settings.robot}:{settings.control_port} (log {settings.log_port}), "
            f"prefix {settings.prefix}, polling at {settings.poll_hz:g} Hz",
            flush=True,
        )
        print(f"  {when_killed(settings.robot)}", flush=True)
        print(f"  e-stop state kept in {service.latch.where}", flush=True)
        if service.start_sentence is not None:
            print(f"  {service.start_sentence}", flush=True)
        announce_ready("gateway", prefix=settings.prefix, cmd_timeout=settings.cmd_timeout)
        freeze_start_up()
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
    return run_single_or_fleet("gateway", args, GatewaySettings, serve, fleet_settings, serve_fleet)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
