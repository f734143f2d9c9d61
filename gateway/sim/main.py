"""``blackmetal sim``: run the simulated robot on real TCP ports, optionally on Zenoh."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
import time
from contextlib import ExitStack

import msgspec

from schemas import SimFaults
from schemas import robot as facts

from ..errors import ConfigError
from ..zenoh_config import ZenohSettings, add_zenoh_arguments, validate_prefix, zenoh_settings
from .robot import RobotParams, SimRobot
from .server import SimServer

log = logging.getLogger("blackmetal.sim")

FAULT_FLAGS = ("dropout", "spike", "full_buffer", "delay", "garbage", "glue", "split", "disconnect")


async def serve(
    robot: SimRobot,
    host: str,
    control_port: int,
    log_port: int,
    log_interval: float,
    zenoh_conf: ZenohSettings | None,
    prefix: str,
    truth_hz: float,
    stop: asyncio.Event,
) -> None:
    """Serve until ``stop`` is set; then close everything within a second or two."""
    server = SimServer(robot, host, control_port, log_port, log_interval=log_interval)
    await server.start()
    print(
        f"blackmetal sim ready: control {host}:{server.control_port}, log {host}:{server.log_port}"
        + (f", truth on {prefix}/sim/truth" if zenoh_conf is not None else ""),
        flush=True,
    )
    with ExitStack() as stack:
        edge = None
        if zenoh_conf is not None:
            import zenoh

            from .zenoh_edge import SimZenohEdge

            session = stack.enter_context(zenoh.open(zenoh_conf.to_config()))
            edge = SimZenohEdge(session, prefix, robot, server.clock)
            stack.callback(edge.close)
        period = 1.0 / truth_hz
        next_tick = time.monotonic()
        try:
            while not stop.is_set():
                if edge is not None:
                    edge.tick()
                else:
                    robot.advance(server.clock())
                next_tick += period
                delay = next_tick - time.monotonic()
                if delay < -period:  # fell behind (loaded machine): do not burst to catch up
                    next_tick = time.monotonic()
                    delay = 0.0
                try:
                    await asyncio.wait_for(stop.wait(), timeout=max(delay, 0.0))
                except (TimeoutError, asyncio.TimeoutError):
                    pass
        finally:
            await server.close()


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="blackmetal sim", description=__doc__)
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--control-port", type=int, default=facts.CONTROL_PORT, help="control port (default 665; 0 = free port)")
    parser.add_argument("--log-port", type=int, default=facts.LOG_PORT, help="log port (default 664; 0 = free port)")
    parser.add_argument("--log-interval", type=float, default=1.0, help="seconds between log-port state reports")
    parser.add_argument("--wheel-separation", type=float, default=facts.WHEEL_SEPARATION, help="m (default 0.5)")
    parser.add_argument("--accel-limit", type=float, default=None, help="motor acceleration limit in m/s^2 (default: none)")
    parser.add_argument("--watchdog", type=float, default=facts.ROBOT_WATCHDOG_S, help="stop after this many seconds without a motion command (default 10)")
    parser.add_argument("--seed", type=int, default=None, help="random seed for faults")
    parser.add_argument("--truth-hz", type=float, default=50.0, help="rate of <prefix>/sim/truth (default 50)")
    parser.add_argument("--prefix", default=None, help="key prefix (default 'robot'); implies Zenoh")
    parser.add_argument("--zenoh", action="store_true", help="publish the truth on Zenoh with default settings")
    faults = parser.add_argument_group("faults (also settable at run time on <prefix>/sim/faults)")
    faults.add_argument("--dropout", type=float, default=0.0, metavar="P", help="per-wheel probability of a stray 0 reading")
    faults.add_argument("--spike", type=float, default=0.0, metavar="P", help="per-wheel probability of an impossible reading")
    faults.add_argument("--full-buffer", type=float, default=0.0, metavar="P", help="probability a command is dropped with FULL_BUFFER")
    faults.add_argument("--delay", type=float, default=0.0, metavar="S", help="delay before every reply (s)")
    faults.add_argument("--garbage", type=float, default=0.0, metavar="P", help="probability of garbage bytes before a reply")
    faults.add_argument("--glue", type=float, default=0.0, metavar="P", help="probability a reply is glued to the next")
    faults.add_argument("--split", type=float, default=0.0, metavar="P", help="probability a reply is split across writes")
    faults.add_argument("--disconnect", type=float, default=0.0, metavar="P", help="probability per request of dropping the connection")
    add_zenoh_arguments(parser)
    return parser


def main(argv: list[str] | None = None, parser: argparse.ArgumentParser | None = None) -> int:
    args = (parser or build_parser()).parse_args(argv)
    return run(args)


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s sim %(levelname)s %(message)s")
    try:
        faults = msgspec.convert({name: getattr(args, name) for name in FAULT_FLAGS}, SimFaults)
        if args.wheel_separation <= 0 or args.watchdog <= 0 or args.truth_hz <= 0 or args.log_interval <= 0:
            raise ConfigError("--wheel-separation, --watchdog, --truth-hz and --log-interval must be positive")
        if args.accel_limit is not None and args.accel_limit <= 0:
            raise ConfigError("--accel-limit must be positive")
        zconf = zenoh_settings(args)
        use_zenoh = zconf.given or args.zenoh or args.prefix is not None
        prefix = validate_prefix(args.prefix or facts.DEFAULT_PREFIX)
    except (ConfigError, msgspec.ValidationError) as exc:
        print(f"blackmetal sim: {exc}", file=sys.stderr)
        return 2
    params = RobotParams(wheel_separation=args.wheel_separation, accel_limit=args.accel_limit, watchdog=args.watchdog)
    robot = SimRobot(params, now=time.monotonic(), seed=args.seed)
    robot.faults = faults

    async def _main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        await serve(
            robot,
            args.host,
            args.control_port,
            args.log_port,
            args.log_interval,
            zconf if use_zenoh else None,
            prefix,
            args.truth_hz,
            stop,
        )

    try:
        asyncio.run(_main())
    except OSError as exc:
        print(f"blackmetal sim: cannot listen: {exc}", file=sys.stderr)
        return 1
    except ConfigError as exc:
        print(f"blackmetal sim: {exc}", file=sys.stderr)
        return 2
    log.info("stopped")
    return 0
