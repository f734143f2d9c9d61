"""Zenoh edge of the odometry service: declarations only, inputs handed over to the host on the service's loop."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import TYPE_CHECKING

from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.edge import ZenohEdge
from blackmetal.runtime.intake import Intake
from blackmetal.schemas import Keys, PayloadError, Pose, encode, payload_bytes

from .host import OdometryHost

if TYPE_CHECKING:
    import zenoh

#: A fleet robot's impulse samples wait in a Zenoh ring of this many for :meth:`OdometryZenoh.drain`: it overflows
#: after a 20 s stall at 50 Hz (1 s at 1000 Hz), dropping the oldest uncounted: the odometry sees a gap in the sequence.
RING = 1024


class OdometryZenoh(ZenohEdge):
    def __init__(self, session: "zenoh.Session", keys: Keys, *, burst: PutBurst | None = None) -> None:
        """One robot: poses go out express; a fleet (``burst``): batched, back to back with the other robots' (docs/performance.md)."""
        super().__init__(session)
        self.keys = keys
        self.routes(keys, (keys.pose, keys.errors), fast=keys.pose, burst=burst)
        self._ring: zenoh.Subscriber[zenoh.handlers.Handler[zenoh.Sample]] | None = None
        self._host: OdometryHost | None = None

    def attach(self, host: OdometryHost, loop: asyncio.AbstractEventLoop, *, ring: bool = False) -> Intake:
        """Declare the inputs that feed ``host``; ``ring`` (a fleet): impulse samples wait for :meth:`drain`, no callback each."""
        intake, keys = self.intake(loop), self.keys
        if ring:
            import zenoh

            self._ring = self.session.declare_subscriber(keys.impulses, zenoh.handlers.RingChannel(RING))
            self._entities.append(self._ring)
            self._host = host
        else:
            self._direct_subscriber(keys.impulses, intake.channel("impulses", host.on_impulses, capacity=4096))
        self.queryable(keys.pose, intake.channel("pose?", lambda q: self._answer(q, keys.pose, lambda _: host.core.latest())))
        self.queryable(keys.odometry_reset, intake.channel("reset?", lambda q: self._answer(q, keys.odometry_reset, host.on_reset)))
        self.queryable(
            keys.errors, intake.channel("errors?", lambda q: self.answer_recent(q, keys.errors, list(host.core.reporter.recent)))
        )
        self.token(keys.alive_odometry)
        return intake

    def drain(self) -> int:
        """On the loop: the ring's impulse samples to the host, oldest first; how many. A handler's exception propagates."""
        ring, host = self._ring, self._host
        if ring is None or host is None:
            return 0
        taken = 0
        while (sample := ring.try_recv()) is not None:
            taken += 1
            host.on_impulses(payload_bytes(sample))
        return taken

    def close(self) -> None:
        self._ring = None  # nothing is drained from an undeclared subscriber
        super().close()

    def _direct_subscriber(self, key: str, put: Callable[[bytes], None]) -> None:
        """:meth:`subscriber` with its callback on Zenoh's receiving thread: it only copies the payload into the hand-over."""
        import zenoh

        handler: zenoh.handlers.Callback[zenoh.Sample] = zenoh.handlers.Callback(lambda sample: put(payload_bytes(sample)), indirect=False)
        self._entities.append(self.session.declare_subscriber(key, handler))

    def _answer(self, query: "zenoh.Query", key: str, pose: Callable[[bytes | None], Pose]) -> None:
        """Reply the pose ``pose(payload)`` gives, or its PayloadError."""
        import zenoh

        with query:
            payload = None if query.payload is None else bytes(query.payload.to_bytes())
            try:
                answer = pose(payload)
            except PayloadError as exc:
                query.reply_err(str(exc).encode())
                return
            query.reply(key, encode(answer), encoding=zenoh.Encoding.APPLICATION_JSON)
