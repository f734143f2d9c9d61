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
from dataclasses import dataclass

from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.edge import refuse_taken
from blackmetal.runtime.fleet import FleetRobot, supervise
from blackmetal.schemas import ErrorReport, Keys

from .core import OdometryCore
from .host import OdometryHost
from .settings import OdometrySettings
from .zenoh_edge import OdometryZenoh

log = logging.getLogger("blackmetal.odometry")

#: How often the fleet's loop takes every robot's waiting impulse samples (s): a pose is at most this much later
#: than a callback would have made it, and the loop wakes 200 times a second for the whole fleet.
DRAIN_PERIOD_S = 0.005


def fleet_settings(base: OdometrySettings, robots: list[FleetRobot]) -> list[OdometrySettings]:
    """Each robot's odometry settings: the command line's, its prefix, its constants and [robot.odometry]."""
    return [robot.settings("odometry", base, {"prefix": robot.prefix}) for robot in robots]


@dataclass
class Member:
    """One robot's odometry in the fleet process (a :class:`~blackmetal.runtime.fleet.Served`): started again from zero after a bug."""

    robot: FleetRobot
    settings: OdometrySettings
    session: object
    #: The fleet's poses, put back to back at the end of each turn of the loop (one for every member).
    burst: PutBurst
    edge: OdometryZenoh | None = None
    host: OdometryHost | None = None
    #: Set with the exception a drain of this robot's samples raised: :meth:`run` raises it, for the supervisor.
    failure: asyncio.Future[None] | None = None

    def start(self) -> Member:
        keys = Keys(self.settings.prefix)
        loop = asyncio.get_running_loop()
        self.edge = OdometryZenoh(self.session, keys, burst=self.burst)  # type: ignore[arg-type]
        self.host = OdometryHost(OdometryCore(self.settings.params(), keys, self.edge.publish))
        self.edge.attach(self.host, loop, ring=True)  # queries and resets through its intake, impulses from its ring
        self.failure = loop.create_future()
        return self

    def drain(self) -> None:
        """On the loop, from the fleet's drain: this robot's waiting impulse samples to its odometry."""
        edge, failure = self.edge, self.failure
        if edge is None or failure is None or failure.done():
            return
        try:
            edge.drain()
        except Exception as exc:  # a bug in this robot's handling: it alone is started again
            failure.set_exception(exc if not isinstance(exc, StopIteration) else RuntimeError(repr(exc)))

    async def run(self, stop: asyncio.Event) -> None:
        assert self.host is not None and self.failure is not None
        failure = self.failure
        serving = asyncio.ensure_future(self.host.run(stop))
        try:
            await asyncio.wait({serving, failure}, return_when=asyncio.FIRST_COMPLETED)
            if failure.done():
                failure.result()
            serving.result()  # the host's own failure (its timers), for the supervisor as well
        finally:
            serving.cancel()
            failure.cancel()

    def failed(self, exc: Exception, pause: float) -> None:
        assert self.edge is not None
        reason = f"odometry of {self.robot.describe()} failed ({exc!r}): starting again from zero in {pause:g} s"
        log.error("%s", reason)
        self.edge.publish(ErrorReport(stamp=time.time(), source="odometry", key=self.edge.keys.pose, reason=reason))

    def close(self) -> None:
        if self.edge is not None:
            self.edge.close()


async def serve_fleet(base: OdometrySettings, robots: list[FleetRobot], stop: asyncio.Event) -> None:
    """Open one Zenoh session and run every robot's odometry on it until ``stop``."""
    import zenoh

    from blackmetal.runtime.harness import announce_ready
    from blackmetal.runtime.zenoh_setup import open_service_session

    settings = fleet_settings(base, robots)
    with await open_service_session(base.zenoh, stop, "odometry") as session:
        by_prefix = {robot.prefix: robot.describe() for robot in robots}
        refuse_taken(session, "odometry", list(by_prefix), what="odometry service", describe=by_prefix.__getitem__)
        assert isinstance(session, zenoh.Session)
        burst = PutBurst()
        members = [Member(r, s, session, burst) for r, s in zip(robots, settings, strict=True)]
        tasks = [asyncio.create_task(supervise(m.start, stop), name=f"odometry {m.robot.id}") for m in members]
        tasks.append(asyncio.create_task(_drain(members, stop), name="odometry drain"))
        print(f"blackmetal odometry ready: a fleet of {len(robots)} robots, {Keys(robots[0].prefix).impulses} -> pose, ...", flush=True)
        announce_ready("odometry", prefix=robots[0].prefix, prefixes=[r.prefix for r in robots])
        try:
            await asyncio.gather(*tasks)
        finally:
            burst.flush()  # what the last turn held; refused if its robot's edge already closed (a normal stop)


async def _drain(members: list[Member], stop: asyncio.Event) -> None:
    """Every DRAIN_PERIOD_S until ``stop``: each robot's waiting impulse samples to its odometry (see OdometryZenoh.drain)."""
    while not stop.is_set():
        for member in members:
            member.drain()
        await asyncio.sleep(DRAIN_PERIOD_S)
