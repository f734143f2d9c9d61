"""``blackmetal gateway --fleet FILE``: one process, one Zenoh session, one supervised robot connection per fleet entry.

Each robot keeps everything a single gateway has: its own sans-I/O core
(safety, command sources, e-stop), its own robot links, its own Zenoh edge,
liveliness token, health and errors under its prefix. What they share is the
process, the asyncio loop and the Zenoh session. A robot's failure stays its
own: a link that drops reconnects alone, a flood is bounded by its own
channels, and a bug in its handling fails only its host, which is stopped
(the robot left standing), reported on its errors key and started again.
"""

from __future__ import annotations

import asyncio
import logging
import os
import time
from dataclasses import dataclass

from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.edge import refuse_taken
from blackmetal.runtime.entry import freeze_start_up
from blackmetal.runtime.fleet import FleetRobot, supervise
from blackmetal.schemas import ErrorReport, Keys
from blackmetal.transport import TcpConnector

from .host import GatewayHost
from .settings import GatewaySettings, when_killed
from .zenoh_edge import GatewayZenoh

log = logging.getLogger("blackmetal.gateway")


def fleet_settings(base: GatewaySettings, robots: list[FleetRobot]) -> list[GatewaySettings]:
    """Each robot's gateway settings: the command line's, its link and prefix, its constants and [robot.gateway]."""
    return [
        robot.settings(
            "gateway",
            base,
            {"robot": robot.host, "control_port": robot.control_port, "log_port": robot.log_port, "prefix": robot.prefix},
        )
        for robot in robots
    ]


@dataclass
class Member:
    """One robot of the fleet: its settings, and the host that serves it now (a :class:`~blackmetal.runtime.fleet.Served`)."""

    robot: FleetRobot
    settings: GatewaySettings
    session: object
    #: The fleet's impulses, put back to back at the end of each turn of the loop (one for every member).
    burst: PutBurst
    host: GatewayHost | None = None
    edge: GatewayZenoh | None = None
    restarts: int = 0

    def start(self) -> Member:
        s = self.settings
        self.edge = GatewayZenoh(self.session, Keys(s.prefix), burst=self.burst)  # type: ignore[arg-type]
        self.host = GatewayHost(s, TcpConnector(s.robot, s.control_port, s.log_port, s.connect_timeout), self.edge.publish, s.latch_store())
        self.edge.attach(self.host, asyncio.get_running_loop())
        return self

    async def run(self, stop: asyncio.Event) -> None:
        assert self.host is not None
        await self.host.run(stop)

    def failed(self, exc: Exception, pause: float) -> None:
        assert self.edge is not None
        self.restarts += 1
        reason = f"gateway of {self.robot.describe()} failed ({exc!r}): the robot was stopped; starting again in {pause:g} s"
        log.error("%s", reason)
        self.edge.publish(ErrorReport(stamp=time.time(), source="gateway", key=self.edge.keys.health, reason=reason))

    def close(self) -> None:
        if self.edge is not None:
            self.edge.close()


async def serve_fleet(base: GatewaySettings, robots: list[FleetRobot], stop: asyncio.Event) -> None:
    """Open one Zenoh session and serve every robot of the fleet on it until ``stop``."""
    from blackmetal.runtime.harness import announce_ready
    from blackmetal.runtime.zenoh_setup import open_service_session

    with await open_service_session(base.zenoh, stop, "gateway") as session:
        settings = fleet_settings(base, robots)
        burst = PutBurst()
        members = [Member(robot, s, session, burst) for robot, s in zip(robots, settings, strict=True)]
        by_prefix = {robot.prefix: robot.describe() for robot in robots}
        refuse_taken(session, "gateway", list(by_prefix), describe=by_prefix.__getitem__)
        tasks = [asyncio.create_task(supervise(m.start, stop), name=f"gateway {m.robot.id}") for m in members]
        await asyncio.sleep(0)  # every robot's edge, host and core are built in its task's first step
        freeze_start_up()
        print(
            f"blackmetal gateway ready: a fleet of {len(members)} robots ({', '.join(r.prefix for r in robots[:3])}"
            f"{', ...' if len(robots) > 3 else ''}), polling at {base.poll_hz:g} Hz",
            flush=True,
        )
        print(f"  {when_killed('HOST')} for each robot", flush=True)
        hosts = {m.robot.id: m.host for m in members if m.host is not None}
        if hosts:
            print(f"  e-stop states kept in {os.path.dirname(next(iter(hosts.values())).latch.where)}", flush=True)
        for robot_id, host in hosts.items():
            if host.start_sentence is not None:
                print(f"  {robot_id}: {host.start_sentence}", flush=True)
        announce_ready(
            "gateway", prefix=robots[0].prefix, prefixes=[r.prefix for r in robots], cmd_timeout=base.cmd_timeout, poll_hz=base.poll_hz
        )
        try:
            await asyncio.gather(*tasks)
        finally:
            burst.flush()  # what the last turn held; refused if its robot's edge already closed (a normal stop)
