"""``blackmetal gateway`` / ``python -m gateway``: the robot's Zenoh gateway."""

from __future__ import annotations

import argparse
import asyncio
import sys

from blackmetal.runtime.edge import refuse_if_taken
from blackmetal.runtime.entry import run_service, service_parser
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.settings import load_settings
from blackmetal.runtime.zenoh_setup import open_session
from blackmetal.transport import TcpConnector
from schemas import Keys

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
    with open_session(settings.zenoh) as session:
        refuse_if_taken(session, keys.alive_gateway, "gateway", keys.prefix)
        edge = GatewayZenoh(session, keys)
        service = GatewayHost(settings, connector, edge)
        edge.attach(service, asyncio.get_running_loop())
        print(
            f"blackmetal gateway ready: robot {settings.robot}:{settings.control_port} (log {settings.log_port}), "
            f"prefix {settings.prefix}, polling at {settings.poll_hz:g} Hz",
            flush=True,
        )
        announce_ready("gateway", prefix=settings.prefix)
        try:
            await service.run(stop)
        finally:
            edge.close()


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    return service_parser("blackmetal gateway", __doc__, GatewaySettings, parser)


def run(args: argparse.Namespace) -> int:
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    return run_service("gateway", lambda: load_settings(GatewaySettings, args), serve)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
