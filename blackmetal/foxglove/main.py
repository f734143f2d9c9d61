"""``blackmetal foxglove``: a live Foxglove view of the robot: pose, transform, path, truth, wheels, status, health, errors.

Open Foxglove (app or desktop), "Open connection", Foxglove WebSocket, and
the URL this prints; then import the layout shipped in
``deploy/foxglove/blackmetal.layout.json``. ``--mcap FILE`` writes the same
channels to an MCAP file as they are sent.
"""

from __future__ import annotations

import argparse
import asyncio

from blackmetal.runtime.entry import run_service, service_parser
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.settings import load_settings
from blackmetal.runtime.zenoh_setup import open_session
from schemas import Keys, require_extra

from .core import LiveView
from .host import FoxgloveHost
from .settings import FoxgloveSettings
from .zenoh_edge import FoxgloveZenoh


async def serve(settings: FoxgloveSettings, stop: asyncio.Event) -> None:
    """Start the server (and the MCAP file), open the Zenoh session, show the robot until ``stop``, close everything."""
    require_extra("blackmetal foxglove", "foxglove", "foxglove")
    keys = Keys(settings.prefix)
    host = FoxgloveHost(settings)
    try:
        view = LiveView(keys, path_length=settings.path_length)
        with open_session(settings.zenoh) as session:
            edge = FoxgloveZenoh(session)
            edge.attach(view, asyncio.get_running_loop())
            address = host.url
            print(f"blackmetal foxglove: {keys.prefix} on {address}", flush=True)
            print(f"  open in Foxglove: Open connection > Foxglove WebSocket > {address}", flush=True)
            print(f"  or https://app.foxglove.dev/?ds=foxglove-websocket&ds.url={address}", flush=True)
            if settings.mcap:
                print(f"  writing the same channels to {settings.mcap}", flush=True)
            announce_ready("foxglove", url=address, port=host.server.port, prefix=keys.prefix)
            try:
                await host.run(stop)
            finally:
                edge.close()
    finally:
        host.close()


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    return service_parser("blackmetal foxglove", __doc__, FoxgloveSettings, parser)


def run(args: argparse.Namespace) -> int:
    return run_service("foxglove", lambda: load_settings(FoxgloveSettings, args), serve)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
