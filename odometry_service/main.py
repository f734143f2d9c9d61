"""``blackmetal odometry`` / ``python -m odometry_service``: impulses in, pose out, on Zenoh."""

from __future__ import annotations

import argparse
import logging
import sys
import threading

from gateway.config import given_options, load_settings
from gateway.errors import ConfigError
from gateway.signals import stop_on_signals
from gateway.zenoh_config import add_zenoh_arguments, zenoh_settings

from .service import OdometryService
from .settings import OdometrySettings, add_odometry_arguments

log = logging.getLogger("blackmetal.odometry")


def serve(settings: OdometrySettings, stop: threading.Event) -> None:
    import zenoh

    from .zenoh_edge import OdometryZenoh

    with zenoh.open(zenoh_settings(settings).to_config()) as session:
        edge = OdometryZenoh(session, settings.prefix)
        service = OdometryService(settings.params(), settings.prefix, edge)
        edge.attach()
        print(f"blackmetal odometry ready: {settings.prefix}/wheels/impulses -> {settings.prefix}/pose", flush=True)
        try:
            edge.serve(service, stop)
        finally:
            edge.close()


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="blackmetal odometry", description=__doc__)
    add_odometry_arguments(parser)
    parser.add_argument("--prefix", help="key-expression prefix (default robot)")
    add_zenoh_arguments(parser)
    return parser


def load(args: argparse.Namespace) -> OdometrySettings:
    options = given_options(args)
    return load_settings(OdometrySettings, options, options.pop("settings", None))


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s odometry %(levelname)s %(message)s")
    try:
        settings = load(args)
    except ConfigError as exc:
        print(f"blackmetal odometry: {exc}", file=sys.stderr)
        return 2
    stop = stop_on_signals()
    try:
        serve(settings, stop)
    except ConfigError as exc:
        print(f"blackmetal odometry: {exc}", file=sys.stderr)
        return 2
    log.info("stopped")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
