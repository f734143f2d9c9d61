"""``blackmetal robots``: list the robots whose gateway is alive (liveliness ``**/alive/gateway``)."""

from __future__ import annotations

import argparse
import sys

import zenoh

from .client import client_settings, where
from .zenoh_config import add_zenoh_arguments


def alive_robots(session: zenoh.Session, timeout: float = 3.0) -> list[str]:
    """Prefixes (``robot``, ``fleet/a``, ...) that have a live gateway."""
    prefixes = set()
    for reply in session.liveliness().get("**/alive/gateway", timeout=timeout):
        if reply.ok is not None:
            prefixes.add(str(reply.ok.key_expr).removesuffix("/alive/gateway"))
    return sorted(prefixes)


def run(args: argparse.Namespace) -> int:
    args.prefix = "robot"  # client_settings validates a prefix; none is used here
    settings = client_settings(args)
    with zenoh.open(settings.to_config()) as session:
        robots = alive_robots(session, args.wait)
    if not robots:
        print(f"blackmetal robots: no live gateway found via {where(settings)} within {args.wait:g} s", file=sys.stderr)
        return 1
    for prefix in robots:
        print(prefix)
    return 0


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="blackmetal robots", description=__doc__)
    parser.add_argument("--wait", type=float, default=3.0, help="seconds to collect answers (default 3)")
    add_zenoh_arguments(parser)
    return parser
