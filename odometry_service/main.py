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

from .service import OdometryService
from .settings import OdometrySettings
from .zenoh_edge import OdometryZenoh

#: How often rate-limited error summaries are published (s).
FLUSH_PERIOD_S = 1.0


async def serve(settings: OdometrySettings, stop: asyncio.Event) -> None:
    keys = Keys(settings.prefix)
    with open_session(settings.zenoh) as session:
        refuse_if_taken(session, keys.alive_odometry, "odometry service", keys.prefix)
        edge = OdometryZenoh(session, keys)
        service = OdometryService(settings.params(), keys, edge)
        handover = edge.attach(service, asyncio.get_running_loop())
        print(f"blackmetal odometry ready: {keys.impulses} -> {keys.pose}", flush=True)
        announce_ready("odometry", prefix=settings.prefix)
        dropped = 0
        try:
            while not stop.is_set():
                try:
                    await asyncio.wait_for(stop.wait(), FLUSH_PERIOD_S)
                except TimeoutError:
                    now_dropped = handover.stats()["impulses"][1]
                    if now_dropped > dropped:
                        service.on_dropped(now_dropped - dropped)
                        dropped = now_dropped
                    service.reporter.flush()
        finally:
            edge.close()


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    return service_parser("blackmetal odometry", __doc__, OdometrySettings, parser)


def run(args: argparse.Namespace) -> int:
    return run_service("odometry", lambda: load_settings(OdometrySettings, args), serve)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
