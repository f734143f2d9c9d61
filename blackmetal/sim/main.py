"""``blackmetal sim``: the simulated robot on real TCP ports, optionally on Zenoh (truth out, faults in)."""

from __future__ import annotations

import argparse
import asyncio
import time
from contextlib import ExitStack

from blackmetal.runtime.entry import run_service, service_parser
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.settings import load_settings
from blackmetal.runtime.zenoh_setup import open_service_session
from blackmetal.schemas import DEFAULT_PREFIX, Keys

from .physics import RobotParams, SimRobot
from .server import SimServer
from .settings import SimSettings


async def serve(settings: SimSettings, stop: asyncio.Event) -> None:
    """Serve until ``stop`` is set; then close everything within a second or two."""
    params = RobotParams.with_wheel_scales(
        left=settings.left_wheel_scale,
        right=settings.right_wheel_scale,
        wheel_separation=settings.wheel_separation,
        accel_limit=settings.accel_limit,
        watchdog=settings.watchdog,
    )
    robot = SimRobot(params, now=time.monotonic(), seed=settings.seed)
    robot.faults = settings.faults()
    server = SimServer(robot, settings.host, settings.control_port, settings.log_port, log_interval=settings.log_interval)
    await server.start()
    keys = Keys(settings.prefix or DEFAULT_PREFIX)
    with ExitStack() as stack:
        edge = None
        if settings.uses_zenoh:
            from .zenoh_edge import SimZenoh

            session = stack.enter_context(await open_service_session(settings.zenoh, stop, "sim"))
            edge = SimZenoh(session, keys, robot, server.clock)
            stack.callback(edge.close)
            edge.attach(asyncio.get_running_loop())
        print(
            f"blackmetal sim ready: control {settings.host}:{server.control_port}, log {settings.host}:{server.log_port}"
            + (f", truth on {keys.sim_truth}" if edge is not None else ""),
            flush=True,
        )
        announce_ready("sim", host=settings.host, control_port=server.control_port, log_port=server.log_port)
        period = 1.0 / settings.truth_hz
        next_tick = time.monotonic()
        try:
            while not stop.is_set():
                if edge is not None:
                    edge.tick()  # the truth while watched, and error summaries when due
                next_tick += period
                delay = next_tick - time.monotonic()
                if delay < -period:  # fell behind (loaded machine): do not burst to catch up
                    next_tick = time.monotonic()
                    delay = 0.0
                try:
                    await asyncio.wait_for(stop.wait(), timeout=max(delay, 0.0))
                except TimeoutError:
                    pass
        finally:
            await server.close()


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = service_parser("blackmetal sim", __doc__, SimSettings, parser)
    fleet = parser.add_mutually_exclusive_group()
    fleet.add_argument("--robots", type=int, metavar="N", help="simulate N robots r1..rN under fleet/<id>, each on free ports")
    fleet.add_argument("--fleet", metavar="FILE", help="simulate the robots of this fleet file, each on its ports")
    parser.add_argument("--write-fleet", metavar="FILE", help="with --robots or --fleet: write the fleet file with the bound ports")
    return parser


def run(args: argparse.Namespace) -> int:
    robots = getattr(args, "robots", None)
    fleet = getattr(args, "fleet", None)
    if robots is not None or fleet:
        from blackmetal.runtime.fleet import FleetRobot, load_fleet, numbered_fleet

        from .fleet import serve_fleet

        def load_fleet_settings() -> tuple[SimSettings, list[FleetRobot]]:
            base = load_settings(SimSettings, args)
            members = load_fleet(fleet) if fleet else numbered_fleet(int(robots or 0), host=base.host)
            return base, members

        return run_service("sim", load_fleet_settings, lambda loaded, stop: serve_fleet(*loaded, stop, args.write_fleet))
    return run_service("sim", lambda: load_settings(SimSettings, args), serve)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
