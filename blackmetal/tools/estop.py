"""``blackmetal estop on|off``: engage or release the emergency stop, and wait until the gateway confirms it.

A bare one-shot ``put`` from a session that closes at once can be lost: the
session may close before Zenoh has delivered the sample (7 times in 10
here). This command keeps its session open, repeats the put every 100 ms
and watches the gateway's health until it reports the new state; it exits 0
then, or 1 with the reason after ``--timeout`` (default 2 s). A release goes
on ``<prefix>/estop/release``, the key a secure router gives to a safety
role alone (the only key a gateway releases on, unless ``--unsafe-release-on-estop``).
"""

from __future__ import annotations

import argparse
import time

from blackmetal.schemas import GatewayHealth

from .client import ToolError, add_client_arguments, connect, query, require_gateway, tool

REPEAT_S = 0.1


@tool("estop")
def run(args: argparse.Namespace) -> int:
    engage = args.state == "on"
    keys, settings, session = connect(args)
    with session:
        require_gateway(session, keys, settings, min(args.wait, args.timeout))  # the whole answer within --timeout
        payload = b'{"engaged": true}' if engage else b'{"engaged": false}'
        key = keys.estop if engage else keys.estop_release
        publisher = session.declare_publisher(key, express=True)
        deadline = time.monotonic() + args.timeout
        while True:
            publisher.put(payload)
            health = query(session, keys.health, GatewayHealth, timeout=REPEAT_S * 5)
            if health is not None and health.estop == engage:
                state = "ENGAGED" if engage else "released"
                print(f"blackmetal estop: {state} on {keys.prefix} (confirmed by the gateway){health.estop_origin()}")
                return 0
            if time.monotonic() > deadline:
                seen = "no health" if health is None else f"health still says estop={health.estop}"
                raise ToolError(
                    f"the gateway on {keys.prefix} did not confirm the e-stop {args.state} within {args.timeout:g} s ({seen}; "
                    f"Zenoh: {settings.where()}). Is this user allowed to put on {key}?"
                )
            time.sleep(REPEAT_S)


def build_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("state", choices=("on", "off"), help="on engages the stop, off releases it")
    parser.add_argument("--timeout", type=float, default=2.0, metavar="S", help="confirmation time limit (default 2)")
    add_client_arguments(parser)
