"""``blackmetal foxglove``: a live Foxglove view of the robot: pose, transform, path, truth, wheels, status, health, errors.

Open Foxglove (app or desktop), "Open connection", Foxglove WebSocket, and
the URL this prints; then import the layout shipped in
``deploy/foxglove/blackmetal.layout.json``. ``--mcap FILE`` writes the same
channels to an MCAP file as they are sent.
"""

from __future__ import annotations

import argparse
import asyncio
from dataclasses import dataclass, field
from typing import Any

from blackmetal.runtime.edge import Handover, ZenohEdge
from blackmetal.runtime.entry import run_service, service_parser
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.settings import load_settings, setting
from blackmetal.runtime.zenoh_setup import ZenohSettings, open_session
from schemas import DEFAULT_PREFIX, ConfigError, Keys, require_extra, validate_prefix


@dataclass(slots=True)
class FoxgloveSettings:
    prefix: str = setting(DEFAULT_PREFIX, "key-expression prefix of the robot, e.g. fleet/a")
    host: str = setting("127.0.0.1", "address the WebSocket server listens on (0.0.0.0: every interface)", metavar="ADDR")
    port: int = setting(8765, "WebSocket port (0: any free port)", metavar="PORT")
    mcap: str | None = setting(None, "also write the view's channels to this MCAP file", metavar="FILE")
    path_length: int = setting(2000, "poses kept in the driven path", metavar="N")
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)

    def check(self) -> None:
        validate_prefix(self.prefix)
        if not 0 <= self.port <= 65535:
            raise ConfigError(f"--port must be 0..65535, got {self.port}")
        if self.path_length < 2:
            raise ConfigError(f"--path-length must be at least 2, got {self.path_length}")


def url(host: str, port: int) -> str:
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    return f"ws://{shown}:{port}"


def start_server(settings: FoxgloveSettings) -> Any:
    import foxglove

    try:
        return foxglove.start_server(name="blackmetal", host=settings.host, port=settings.port)
    except Exception as exc:  # the SDK raises its own error with the OS reason
        raise ConfigError(
            f"cannot serve Foxglove on {settings.host}:{settings.port} ({exc}); is another server on that port? try --port 0 or another port"
        ) from None


async def serve(settings: FoxgloveSettings, stop: asyncio.Event) -> None:
    require_extra("blackmetal foxglove", "foxglove", "foxglove")
    import foxglove

    from .view import LiveView

    keys = Keys(settings.prefix)
    server = start_server(settings)
    writer = None
    try:
        if settings.mcap:
            try:
                writer = foxglove.open_mcap(settings.mcap, allow_overwrite=True)
            except Exception as exc:
                raise ConfigError(f"cannot write {settings.mcap}: {exc}") from None
        view = LiveView(keys, path_length=settings.path_length)
        with open_session(settings.zenoh) as session:
            edge = ZenohEdge(session)
            handover = Handover(asyncio.get_running_loop())
            for key, handler in view.handlers().items():
                edge.subscriber(key, handover.channel(key, handler, capacity=512))
            address = url(settings.host, server.port)
            print(f"blackmetal foxglove: {keys.prefix} on {address}", flush=True)
            print(f"  open in Foxglove: Open connection > Foxglove WebSocket > {address}", flush=True)
            print(f"  or https://app.foxglove.dev/?ds=foxglove-websocket&ds.url={address}", flush=True)
            if settings.mcap:
                print(f"  writing the same channels to {settings.mcap}", flush=True)
            announce_ready("foxglove", url=address, port=server.port, prefix=keys.prefix)
            try:
                await stop.wait()
            finally:
                edge.close()
    finally:
        if writer is not None:
            writer.close()
        server.stop()


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    return service_parser("blackmetal foxglove", __doc__, FoxgloveSettings, parser)


def run(args: argparse.Namespace) -> int:
    return run_service("foxglove", lambda: load_settings(FoxgloveSettings, args), serve)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
