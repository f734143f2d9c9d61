"""One robot's service in a fleet process, supervised, and the one ``serve_fleet`` that runs them all.

A service with ``--fleet FILE`` declares a :class:`Role` (how to build one robot's edge and host, how its failure
reads); the rest is shared: a :class:`Member` per robot, rebuilt alone when a bug in its handling fails it.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from blackmetal.schemas import ErrorReport

from .burst import PutBurst
from .edge import refuse_taken
from .fleet import FleetRobot
from .zenoh_setup import ZenohSettings, open_service_session

S = TypeVar("S")  # a service's settings

#: A robot whose service failed of a bug is started again after this pause, doubling up to RESTART_CAP_S.
RESTART_FIRST_S = 0.5
RESTART_CAP_S = 10.0


@dataclass(frozen=True)
class Role(Generic[S]):
    """What a service declares about one robot of its fleet."""

    #: Who the service is: its Zenoh session, its logger, its tasks' names and its error reports' source.
    service: str
    #: One robot's edge and host, attached to the running loop; called again after a failure (a new edge, new ids).
    build: Callable[[Member[S]], tuple[Any, Any]]
    #: The failure's sentence, formatted with ``robot`` (who), ``exc`` and ``pause`` (s until it starts again).
    failure: str
    #: The ``Keys`` attribute the failure's report names.
    error_key: str = "errors"


@dataclass(eq=False)
class Member(Generic[S]):
    """One robot of a fleet process: its settings, and the edge and host that serve it now."""

    role: Role[S]
    robot: FleetRobot
    settings: S
    session: Any
    #: The fleet's volatile samples, put back to back at the end of each turn of the loop (one for every member).
    burst: PutBurst
    edge: Any = None
    host: Any = None
    #: Set with the exception a drain of this robot's samples raised: :meth:`run` raises it, for the supervisor.
    failure: asyncio.Future[None] | None = None

    def start(self) -> Member[S]:
        """Build the robot's edge and host unless they are built (before the fleet is announced); after a failure, anew."""
        if self.edge is None:
            self.edge, self.host = self.role.build(self)
            self.failure = asyncio.get_running_loop().create_future()
        return self

    def drain(self) -> bool:
        """On the loop: this robot's waiting samples from its rings to its core; False when it follows none (an idle view)."""
        edge, failure = self.edge, self.failure
        if edge is None or failure is None or failure.done() or not getattr(edge, "following", lambda: True)():
            return False
        try:
            edge.drain()
        except Exception as exc:  # a bug in this robot's handling: it alone is started again
            self.fail(exc)
        return True

    def fail(self, exc: Exception) -> None:
        """A bug in this robot's handling: :meth:`run` ends with it. A host that supervises its core (``fail``) is told
        instead: it stops taking samples on Zenoh's threads at once, and its run ends with the failure."""
        host_fail = getattr(self.host, "fail", None)
        if host_fail is not None:
            host_fail(exc)
        elif self.failure is not None and not self.failure.done():
            self.failure.set_exception(exc if not isinstance(exc, StopIteration) else RuntimeError(repr(exc)))

    async def run(self, stop: asyncio.Event) -> None:
        """Serve until ``stop``; raises the failure of its host or of a drain."""
        assert self.host is not None and self.failure is not None
        failure = self.failure
        serving = asyncio.ensure_future(self.host.run(stop))
        try:
            await asyncio.wait({serving, failure}, return_when=asyncio.FIRST_COMPLETED)
            if failure.done():
                failure.result()
            serving.result()
        finally:
            serving.cancel()
            failure.cancel()

    def close(self) -> None:
        """Undeclare what the robot's edge declared; the next :meth:`start` builds anew."""
        if self.edge is not None:
            self.edge.close()
        self.edge = self.host = self.failure = None


async def supervise(member: Member[Any], stop: asyncio.Event) -> None:
    """Run ``member`` until ``stop``; one that fails is reported and started again.

    A failure stays that robot's: the others share the loop and go on. The pause doubles from RESTART_FIRST_S up to
    RESTART_CAP_S, so a robot that fails at once costs the fleet little.
    """
    pause, role = RESTART_FIRST_S, member.role
    while not stop.is_set():
        member.start()
        try:
            await member.run(stop)
            return
        except Exception as exc:
            logging.getLogger("blackmetal.fleet").debug("a fleet member failed", exc_info=exc)
            reason = role.failure.format(robot=member.robot.describe(), exc=exc, pause=pause)
            logging.getLogger(f"blackmetal.{role.service}").error("%s", reason)
            key = getattr(member.edge.keys, role.error_key)  # reported on the robot's errors key: its edge is still open
            member.edge.publish(ErrorReport(stamp=time.time(), source=role.service, key=key, reason=reason))
        finally:
            member.close()
        try:
            await asyncio.wait_for(stop.wait(), pause)
        except TimeoutError:
            pass
        pause = min(pause * 2, RESTART_CAP_S)


async def drain(members: Sequence[Member[Any]], stop: asyncio.Event, period: float, idle_period: float | None = None) -> None:
    """Every ``period`` until ``stop``: each member's waiting samples to its core (see :meth:`Member.drain`).

    With ``idle_period``, while no member follows anything (nobody watches) it looks only that often: an idle fleet
    costs nothing, and the first samples after someone subscribes wait at most that long in their ring.
    """
    while not stop.is_set():
        active = [member.drain() for member in members]
        await asyncio.sleep(period if idle_period is None or any(active) else idle_period)


async def serve_fleet(
    zenoh: ZenohSettings,
    stop: asyncio.Event,
    parts: Sequence[tuple[Role[S], FleetRobot, S]],
    announce: Callable[[list[Member[S]]], None],
    *,
    refuse: str | None = None,
    drain_every: tuple[float, float | None] | None = None,
) -> None:
    """Open one Zenoh session and serve every robot of ``parts`` (role, robot, its settings) on it until ``stop``.

    ``refuse``: first refuse a prefix on which another such service (named so) is alive. Every robot is built before
    ``announce(members)`` says the fleet serves; ``drain_every`` (period, idle period) drains their rings.
    """
    service = parts[0][0].service
    with await open_service_session(zenoh, stop, service) as session:
        if refuse is not None:
            by_prefix = {robot.prefix: robot.describe() for _, robot, _ in parts}
            refuse_taken(session, service, list(by_prefix), what=refuse, describe=by_prefix.__getitem__)
        burst = PutBurst()
        members = [Member(role, robot, settings, session, burst) for role, robot, settings in parts]
        try:
            for member in members:
                member.start()
            announce(members)
            tasks = [asyncio.create_task(supervise(m, stop), name=f"{service} {m.robot.id}") for m in members]
            if drain_every is not None:
                tasks.append(asyncio.create_task(drain(members, stop, *drain_every), name=f"{service} drain"))
            await asyncio.gather(*tasks)
        finally:
            burst.flush()  # what the last turn held; refused if its robot's edge already closed (a normal stop)
            for member in members:
                member.close()
