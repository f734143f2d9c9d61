"""``blackmetal gateway`` / ``python -m gateway``: the robot's Zenoh gateway."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys

from .config import given_options, load_settings
from .errors import ConfigError
from .link import TcpConnector
from .service import GatewayService
from .settings import GatewaySettings
from .zenoh_config import add_zenoh_arguments, zenoh_settings

log = logging.getLogger("blackmetal.gateway")

SWITCH_INTERVAL_S = 0.0005


async def serve(settings: GatewaySettings, stop: asyncio.Event) -> None:
    """Open the Zenoh session, run the service until ``stop``, close everything."""
    import zenoh

    from .zenoh_edge import GatewayZenoh

    connector = TcpConnector(settings.robot, settings.control_port, settings.log_port, settings.connect_timeout)
    with zenoh.open(zenoh_settings(settings).to_config()) as session:
        edge = GatewayZenoh(session, settings.prefix)
        service = GatewayService(settings, connector, edge)
        edge.attach(service, asyncio.get_running_loop())
        print(
            f"blackmetal gateway ready: robot {settings.robot}:{settings.control_port} (log {settings.log_port}), "
            f"prefix {settings.prefix}, polling at {settings.poll_hz:g} Hz",
            flush=True,
        )
        try:
            await service.run(stop)
        finally:
            edge.close()


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="blackmetal gateway", description=__doc__)
    parser.add_argument("--settings", metavar="FILE", help="settings file (TOML or JSON5) with the same names as the options")
    parser.add_argument("--robot", metavar="HOST", help="robot address (default 127.0.0.1: a local simulator)")
    parser.add_argument("--control-port", type=int, help="robot control port (default 665)")
    parser.add_argument("--log-port", type=int, help="robot log port (default 664)")
    parser.add_argument("--poll-hz", type=float, help="wheel-speed polls per second (default 50)")
    parser.add_argument("--wheel-separation", type=float, help="m (default 0.5)")
    parser.add_argument("--max-wheel-speed", type=float, help="per-wheel limit in m/s (default 0.8)")
    parser.add_argument("--cmd-timeout", type=float, help="brake after this many seconds without cmd_vel (default 0.5, 0 disables)")
    parser.add_argument("--keepalive", type=float, help="repeat an unchanged motion command this often, s (default 5)")
    parser.add_argument("--linear-accel", type=float, help="acceleration limit, m/s^2 (default off)")
    parser.add_argument("--angular-accel", type=float, help="angular acceleration limit, rad/s^2 (default off)")
    parser.add_argument("--max-command-hz", type=float, help="cap on velocity commands per second to the robot; a flood is coalesced to the latest (default 500, so the latest command waits at most 2 ms)")
    parser.add_argument("--prefix", help="key-expression prefix (default robot)")
    add_zenoh_arguments(parser)
    return parser


def run(args: argparse.Namespace) -> int:
    # Zenoh delivers samples on its own threads; a short GIL switch interval lets
    # them hand a command over without waiting out the default 5 ms slice.
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s gateway %(levelname)s %(message)s")
    options = given_options(args)
    try:
        settings = load_settings(GatewaySettings, options, options.pop("settings", None))
    except ConfigError as exc:
        print(f"blackmetal gateway: {exc}", file=sys.stderr)
        return 2

    async def _main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        await serve(settings, stop)

    try:
        asyncio.run(_main())
    except ConfigError as exc:
        print(f"blackmetal gateway: {exc}", file=sys.stderr)
        return 2
    log.info("stopped")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
