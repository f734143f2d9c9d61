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
import time
from dataclasses import dataclass

from blackmetal.runtime.fleet import FleetRobot
from blackmetal.transport import TcpConnector
from schemas import ANY_GATEWAY_ALIVE, ConfigError, ErrorReport, Keys

from .host import GatewayHost
from .settings import GatewaySettings
from .zenoh_edge import GatewayZenoh

log = logging.getLogger("blackmetal.gateway")

#: A robot whose host failed is started again after this pause, doubling up to RESTART_CAP_S.
RESTART_FIRST_S = 0.5
RESTART_CAP_S = 10.0


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
    """One robot of the fleet: its settings, and the host that serves it now."""

    robot: FleetRobot
    settings: GatewaySettings
    host: GatewayHost | None = None
    restarts: int = 0

    async def supervise(self, session: object, stop: asyncio.Event) -> None:
        """Serve this robot until ``stop``; a host that fails of a bug is reported and started again."""
        pause = RESTART_FIRST_S
        loop = asyncio.get_running_loop()
        keys = Keys(self.settings.prefix)
        while not stop.is_set():
            s = self.settings
            edge = GatewayZenoh(session, keys, batched=True)  # type: ignore[arg-type]
            self.host = GatewayHost(s, TcpConnector(s.robot, s.control_port, s.log_port, s.connect_timeout), edge)
            edge.attach(self.host, loop)
            try:
                await self.host.run(stop)
                return
            except Exception as exc:
                self.restarts += 1
                reason = f"gateway of {self.robot.describe()} failed ({exc!r}): the robot was stopped; starting again in {pause:g} s"
                log.error("%s", reason)
                edge.error(ErrorReport(stamp=time.time(), source="gateway", key=keys.health, reason=reason))
            finally:
                edge.close()
            try:
                await asyncio.wait_for(stop.wait(), pause)
            except TimeoutError:
                pass
            pause = min(pause * 2, RESTART_CAP_S)


def refuse_taken_prefixes(session: object, robots: list[FleetRobot], timeout: float = 0.5) -> None:
    """ConfigError naming the first robot whose prefix already has a live gateway (one query for the whole fleet)."""
    import zenoh

    assert isinstance(session, zenoh.Session)
    alive = {
        Keys.prefix_of_gateway_token(str(reply.ok.key_expr))
        for reply in session.liveliness().get(ANY_GATEWAY_ALIVE, timeout=timeout)
        if reply.ok is not None
    }
    for robot in robots:
        if robot.prefix in alive:
            raise ConfigError(
                f"{robot.describe()}: another gateway is already alive on prefix {robot.prefix!r}; "
                "one robot per prefix: stop the other one, or give this robot another prefix"
            )


async def serve_fleet(base: GatewaySettings, robots: list[FleetRobot], stop: asyncio.Event) -> None:
    """Open one Zenoh session and serve every robot of the fleet on it until ``stop``."""
    from blackmetal.runtime.harness import announce_ready
    from blackmetal.runtime.zenoh_setup import open_service_session

    members = [Member(robot, settings) for robot, settings in zip(robots, fleet_settings(base, robots), strict=True)]
    with await open_service_session(base.zenoh, stop, "gateway") as session:
        refuse_taken_prefixes(session, robots)
        tasks = [asyncio.create_task(m.supervise(session, stop), name=f"gateway {m.robot.id}") for m in members]
        print(
            f"blackmetal gateway ready: a fleet of {len(members)} robots ({', '.join(r.prefix for r in robots[:3])}"
            f"{', ...' if len(robots) > 3 else ''}), polling at {base.poll_hz:g} Hz",
            flush=True,
        )
        announce_ready("gateway", prefix=robots[0].prefix, prefixes=[r.prefix for r in robots], cmd_timeout=base.cmd_timeout)
        await asyncio.gather(*tasks)
