"""``blackmetal robots``: list the robots whose gateway is alive (liveliness ``**/alive/gateway``)."""

from __future__ import annotations

import argparse
import sys
import time

import zenoh

from blackmetal.runtime.zenoh_setup import ZenohSettings, add_zenoh_arguments
from schemas import ANY_GATEWAY_ALIVE, Keys, ZenohUnavailable

from .client import connect, tool, where

#: How often the router is tried again while --wait lasts.
RETRY_S = 0.2
#: Tokens are collected at least this long once connected (a router that came up late still gets its answers).
MIN_COLLECT_S = 1.0


def alive_robots(session: zenoh.Session, timeout: float = 5.0) -> list[str]:
    """Prefixes (``robot``, ``fleet/a``, ...) that have a live gateway.

    A liveliness subscriber with history collects the tokens for ``timeout``
    seconds: a single early ``get`` can miss tokens the router has not yet
    told a freshly connected session about.
    """
    prefixes: set[str] = set()
    subscriber = session.liveliness().declare_subscriber(ANY_GATEWAY_ALIVE, history=True)
    try:
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            sample = subscriber.try_recv()
            if sample is None:
                time.sleep(min(0.05, left))
            elif sample.kind == zenoh.SampleKind.PUT:
                prefixes.add(Keys.prefix_of_gateway_token(str(sample.key_expr)))
    finally:
        subscriber.undeclare()
    return sorted(prefixes)


def connect_within(args: argparse.Namespace, deadline: float) -> tuple[ZenohSettings, zenoh.Session]:
    """The tool's session; a router that comes up before ``deadline`` is still met (scripts start it just before).

    When nothing answers by then, the same one sentence as every tool.
    """
    while True:
        try:
            _, settings, session = connect(args)
            return settings, session
        except ZenohUnavailable as exc:
            if "cannot reach" not in str(exc) or time.monotonic() + RETRY_S > deadline:
                raise
        time.sleep(RETRY_S)


@tool("robots")
def run(args: argparse.Namespace) -> int:
    deadline = time.monotonic() + args.wait
    settings, session = connect_within(args, deadline)
    with session:
        robots = alive_robots(session, max(deadline - time.monotonic(), MIN_COLLECT_S))
    if not robots:
        print(f"blackmetal robots: no live gateway found via {where(settings)} within {args.wait:g} s", file=sys.stderr)
        return 1
    for prefix in robots:
        print(prefix)
    return 0


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="blackmetal robots", description=__doc__)
    parser.add_argument(
        "--wait", type=float, default=5.0, help="seconds to reach the router and collect answers (default 5, like every tool)"
    )
    add_zenoh_arguments(parser)
    return parser
