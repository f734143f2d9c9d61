"""``blackmetal router -c deploy/zenoh/router.json5``: a Zenoh router from the Python wheel.

For setups without ``zenohd`` (and for tests): the same JSON5 configuration
files, access control and authentication included. ``-l`` replaces the
listen endpoints of the file.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading

import zenoh

from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.signals import stop_on_signals
from blackmetal.runtime.zenoh_setup import ZenohSettings, unavailable_reason

from .client import ToolError, tool

#: How long the router waits for Zenoh to close before it exits without it (s).
CLOSE_TIMEOUT_S = 5.0
#: How often the main thread wakes to run a signal handler that another thread received (s).
SIGNAL_POLL_S = 0.2


@tool("router")
def run(args: argparse.Namespace) -> int:
    settings = ZenohSettings(mode="router", listen=list(args.listen or []), config=args.config,
                             connect=list(args.connect or []), no_multicast_scouting=bool(args.no_multicast_scouting),
                             multicast_scouting=bool(args.multicast_scouting))  # fmt: skip
    settings.user = settings.password = None  # a router authenticates others from its own config
    conf = settings.to_config()  # a ConfigError: exit 2
    listen: list[str] = json.loads(conf.get_json("listen/endpoints"))  # the file's, where -l gave none
    settings.listen = settings.listen or listen  # so that "in use" names the port
    stop = stop_on_signals()
    try:
        session = zenoh.open(conf)
    except Exception as exc:
        raise ToolError(unavailable_reason(settings, str(exc))) from None
    try:
        print(f"blackmetal router ready: {session.zid()} listening on {', '.join(listen) or 'nothing'}", flush=True)
        announce_ready("router", zid=str(session.zid()), listen=listen)
        # with a timeout: a SIGTERM that the kernel hands to one of Zenoh's threads is run by Python only
        # once the main thread runs Python again; a wait without one never does (the README's fleet recipe
        # left the router running 120 s after SIGTERM in 3 of 11 CI runs)
        while not stop.wait(SIGNAL_POLL_S):
            pass
    finally:
        # bounded: a router must end on SIGTERM even if Zenoh's close hangs while every client leaves at once
        closing = threading.Thread(target=session.close, name="router-close", daemon=True)
        closing.start()
        closing.join(CLOSE_TIMEOUT_S)
        if closing.is_alive():
            print(f"blackmetal router: Zenoh did not close within {CLOSE_TIMEOUT_S:g} s; exiting anyway", file=sys.stderr, flush=True)
            sys.stdout.flush()
            os._exit(0)
    return 0


def build_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-c", "--config", metavar="FILE", help="Zenoh router configuration (JSON5)")
    parser.add_argument("-l", "--listen", action="append", metavar="ENDPOINT", help="listen endpoint, replaces the file's (repeatable)")
    parser.add_argument("-e", "--connect", action="append", metavar="ENDPOINT", help="another router to connect to (repeatable)")
    parser.add_argument("--multicast-scouting", action="store_true", help="discover peers and routers on the LAN (default: off)")
    parser.add_argument("--no-multicast-scouting", action="store_true", help="no discovery (the default; accepted for older scripts)")
