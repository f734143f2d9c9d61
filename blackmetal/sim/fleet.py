"""``blackmetal sim --robots N`` / ``--fleet FILE``: many simulated robots in one process, each on its own ports.

Every robot is a full simulator: its own physics, faults, control and log
ports, and (with Zenoh) its truth and fault keys under its own prefix. With
``--robots N`` the robots are ``r1`` ... ``rN`` under ``fleet/<id>`` on free
ports; ``--write-fleet FILE`` writes the fleet file the gateway and the
odometry then read (``--fleet FILE``), with the ports actually bound.
"""

from __future__ import annotations

import asyncio
import dataclasses
import time
from contextlib import ExitStack
from pathlib import Path

from blackmetal.runtime.fleet import FleetRobot, write_fleet
from blackmetal.runtime.harness import announce_ready
from blackmetal.schemas import Keys

from .physics import RobotParams, SimRobot
from .server import SimServer
from .settings import SimSettings


@dataclasses.dataclass
class FleetMember:
    robot: FleetRobot
    sim: SimRobot
    server: SimServer
    edge: object | None = None


async def serve_fleet(base: SimSettings, robots: list[FleetRobot], stop: asyncio.Event, write_to: str | None = None) -> None:
    """Serve every robot until ``stop``; ``base`` is the command line's SimSettings (each robot's defaults)."""
    members: list[FleetMember] = []
    for robot in robots:
        s = robot.settings("sim", base, {"host": robot.host, "control_port": robot.control_port, "log_port": robot.log_port})
        params = RobotParams.with_wheel_scales(
            left=s.left_wheel_scale,
            right=s.right_wheel_scale,
            wheel_separation=s.wheel_separation,
            accel_limit=s.accel_limit,
            watchdog=s.watchdog,
        )
        sim = SimRobot(params, now=time.monotonic(), seed=None if s.seed is None else s.seed + robot.index)
        sim.faults = s.faults()
        server = SimServer(sim, s.host, s.control_port, s.log_port, log_interval=s.log_interval)
        await server.start()
        members.append(FleetMember(dataclasses.replace(robot, control_port=server.control_port, log_port=server.log_port), sim, server))
    bound = [m.robot for m in members]
    if write_to:
        Path(write_to).write_text(write_fleet(bound))
    with ExitStack() as stack:
        if base.uses_zenoh:
            from blackmetal.runtime.zenoh_setup import open_service_session

            from .zenoh_edge import SimZenoh

            session = stack.enter_context(await open_service_session(base.zenoh, stop, "sim"))
            for m in members:
                edge = SimZenoh(session, Keys(m.robot.prefix), m.sim, m.server.clock)
                stack.callback(edge.close)
                edge.attach(asyncio.get_running_loop())
                m.edge = edge
        print(
            f"blackmetal sim ready: a fleet of {len(members)} robots on ports "
            f"{bound[0].control_port}/{bound[0].log_port} ... {bound[-1].control_port}/{bound[-1].log_port}"
            + (f"; fleet file {write_to}" if write_to else ""),
            flush=True,
        )
        announce_ready("sim", robots=[[r.id, r.prefix, r.control_port, r.log_port] for r in bound], fleet=write_to)
        period = 1.0 / base.truth_hz
        next_tick = time.monotonic()
        try:
            while not stop.is_set():
                for m in members:
                    if m.edge is not None:
                        m.edge.tick()  # type: ignore[attr-defined]
                next_tick += period
                delay = next_tick - time.monotonic()
                if delay < -period:
                    next_tick = time.monotonic()
                    delay = 0.0
                try:
                    await asyncio.wait_for(stop.wait(), timeout=max(delay, 0.0))
                except TimeoutError:
                    pass
        finally:
            for m in members:
                await m.server.close()
