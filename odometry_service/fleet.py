"""``blackmetal odometry --fleet FILE``: one process, one Zenoh session, one odometry per robot of the fleet.

Each robot keeps its own pipeline (glitch filter, sample order, integrator),
its own keys, liveliness token and error reports under its prefix; they
share the process, its loop and the session. A robot whose handling fails
of a bug is reported on its errors key and started again from zero; the
others go on.
"""

from __future__ import annotations

import asyncio
import logging
import time

from blackmetal.runtime.fleet import FleetRobot
from schemas import ConfigError, ErrorReport, Keys

from .core import OdometryCore
from .host import OdometryHost
from .settings import OdometrySettings
from .zenoh_edge import OdometryZenoh

log = logging.getLogger("blackmetal.odometry")

#: A robot whose odometry failed is started again after this pause, doubling up to RESTART_CAP_S.
RESTART_FIRST_S = 0.5
RESTART_CAP_S = 10.0


def fleet_settings(base: OdometrySettings, robots: list[FleetRobot]) -> list[OdometrySettings]:
    """Each robot's odometry settings: the command line's, its prefix, its constants and [robot.odometry]."""
    return [robot.settings("odometry", base, {"prefix": robot.prefix}) for robot in robots]


async def _supervise(session: object, robot: FleetRobot, settings: OdometrySettings, stop: asyncio.Event) -> None:
    keys = Keys(settings.prefix)
    pause = RESTART_FIRST_S
    while not stop.is_set():
        edge = OdometryZenoh(session, keys, batched=True)  # type: ignore[arg-type]
        host = OdometryHost(OdometryCore(settings.params(), keys, edge))
        handover = edge.attach(host, asyncio.get_running_loop())
        try:
            await host.run(stop, dropped=lambda h=handover: h.stats()["impulses"][1])  # type: ignore[misc]
            return
        except Exception as exc:
            reason = f"odometry of {robot.describe()} failed ({exc!r}): starting again from zero in {pause:g} s"
            log.error("%s", reason)
            edge.error(ErrorReport(stamp=time.time(), source="odometry", key=keys.pose, reason=reason))
        finally:
            edge.close()
        try:
            await asyncio.wait_for(stop.wait(), pause)
        except TimeoutError:
            pass
        pause = min(pause * 2, RESTART_CAP_S)


async def serve_fleet(base: OdometrySettings, robots: list[FleetRobot], stop: asyncio.Event) -> None:
    """Open one Zenoh session and run every robot's odometry on it until ``stop``."""
    import zenoh

    from blackmetal.runtime.harness import announce_ready
    from blackmetal.runtime.zenoh_setup import open_service_session

    settings = fleet_settings(base, robots)
    with await open_service_session(base.zenoh, stop, "odometry") as session:
        alive = {str(r.ok.key_expr) for r in session.liveliness().get("**/alive/odometry", timeout=0.5) if r.ok is not None}
        for robot in robots:
            if Keys(robot.prefix).alive_odometry in alive:
                raise ConfigError(f"{robot.describe()}: another odometry service is already alive on prefix {robot.prefix!r}")
        assert isinstance(session, zenoh.Session)
        tasks = [
            asyncio.create_task(_supervise(session, r, s, stop), name=f"odometry {r.id}") for r, s in zip(robots, settings, strict=True)
        ]
        print(f"blackmetal odometry ready: a fleet of {len(robots)} robots, {Keys(robots[0].prefix).impulses} -> pose, ...", flush=True)
        announce_ready("odometry", prefix=robots[0].prefix, prefixes=[r.prefix for r in robots])
        await asyncio.gather(*tasks)
