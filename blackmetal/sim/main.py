"""``blackmetal sim``: the simulated robot on real TCP ports, optionally on Zenoh (truth out, faults in)."""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import time
from collections.abc import Callable
from contextlib import ExitStack, suppress
from pathlib import Path

from blackmetal.runtime.entry import run_service, service_parser
from blackmetal.runtime.fleet import FleetRobot, load_fleet, numbered_fleet, write_fleet
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.settings import load_settings
from blackmetal.schemas import DEFAULT_PREFIX, Keys

from .physics import RobotParams, SimRobot
from .server import SimServer
from .settings import SimSettings


async def start_robot(s: SimSettings, seed: int | None) -> tuple[SimRobot, SimServer]:
    params = RobotParams.with_wheel_scales(
        left=s.left_wheel_scale,
        right=s.right_wheel_scale,
        wheel_separation=s.wheel_separation,
        accel_limit=s.accel_limit,
        watchdog=s.watchdog,
    )
    robot = SimRobot(params, now=time.monotonic(), seed=seed)
    robot.faults = s.faults()
    server = SimServer(robot, s.host, s.control_port, s.log_port, log_interval=s.log_interval)
    await server.start()
    return robot, server


async def serve_robots(
    settings: SimSettings, robots: list[tuple[str, SimRobot, SimServer]], stop: asyncio.Event, announce: Callable[[bool], None]
) -> None:
    """On Zenoh if the settings say so (truth out, faults in, under each prefix), ``announce(on_zenoh)``, then tick each
    robot's truth at ``truth_hz`` until ``stop``; the servers close at the end."""
    with ExitStack() as stack:
        edges = []
        if settings.uses_zenoh:
            from blackmetal.runtime.zenoh_setup import open_service_session

            from .zenoh_edge import SimZenoh

            session = stack.enter_context(await open_service_session(settings.zenoh, stop, "sim"))
            for prefix, robot, server in robots:
                edge = SimZenoh(session, Keys(prefix), robot, server.clock)
                stack.callback(edge.close)
                edge.attach(asyncio.get_running_loop())
                edges.append(edge)
        announce(bool(edges))
        period = 1.0 / settings.truth_hz
        next_tick = time.monotonic()
        try:
            while not stop.is_set():
                for edge in edges:
                    edge.tick()  # the truth while watched, and error summaries when due
                next_tick += period
                delay = next_tick - time.monotonic()
                if delay < -period:  # fell behind (loaded machine): do not burst to catch up
                    next_tick = time.monotonic()
                    delay = 0.0
                with suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), timeout=max(delay, 0.0))
        finally:
            for _, _, server in robots:
                await server.close()


async def serve(settings: SimSettings, stop: asyncio.Event) -> None:
    robot, server = await start_robot(settings, settings.seed)
    keys = Keys(settings.prefix or DEFAULT_PREFIX)

    def announce(on_zenoh: bool) -> None:
        ports = f"control {settings.host}:{server.control_port}, log {settings.host}:{server.log_port}"
        truth = f", truth on {keys.sim_truth}" if on_zenoh else ""
        print(f"blackmetal sim ready: {ports}{truth}", flush=True)
        announce_ready("sim", host=settings.host, control_port=server.control_port, log_port=server.log_port)

    await serve_robots(settings, [(keys.prefix, robot, server)], stop, announce)


async def serve_fleet(base: SimSettings, robots: list[FleetRobot], stop: asyncio.Event, write_to: str | None = None) -> None:
    """``--robots N`` / ``--fleet FILE``: every robot, each a full simulator, until ``stop``; ``base`` holds each
    robot's defaults; ``write_to`` (``--write-fleet``) gets the fleet file with the ports actually bound."""
    started, bound = [], []
    for robot in robots:
        s = robot.settings("sim", base, {"host": robot.host, "control_port": robot.control_port, "log_port": robot.log_port})
        sim, server = await start_robot(s, None if s.seed is None else s.seed + robot.index)
        started.append((robot.prefix, sim, server))
        bound.append(dataclasses.replace(robot, control_port=server.control_port, log_port=server.log_port))
    if write_to:
        Path(write_to).write_text(write_fleet(bound))

    def announce(on_zenoh: bool) -> None:
        ports = f"{bound[0].control_port}/{bound[0].log_port} ... {bound[-1].control_port}/{bound[-1].log_port}"
        fleet_file = f"; fleet file {write_to}" if write_to else ""
        print(f"blackmetal sim ready: a fleet of {len(bound)} robots on ports {ports}{fleet_file}", flush=True)
        announce_ready("sim", robots=[[r.id, r.prefix, r.control_port, r.log_port] for r in bound], fleet=write_to)

    await serve_robots(base, started, stop, announce)


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
    if robots is None and not fleet:
        return run_service("sim", lambda: load_settings(SimSettings, args), serve)

    def load_fleet_settings() -> tuple[SimSettings, list[FleetRobot]]:
        base = load_settings(SimSettings, args)
        return base, load_fleet(fleet) if fleet else numbered_fleet(int(robots or 0), host=base.host)

    return run_service("sim", load_fleet_settings, lambda loaded, stop: serve_fleet(*loaded, stop, args.write_fleet))


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
