"""Zenoh edge of the odometry service: declarations only, inputs handed over to the host on the service's loop."""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING

from blackmetal.runtime.edge import Handover, ZenohEdge
from schemas import ErrorReport, Keys, PayloadError, Pose, encode

from .host import OdometryHost

if TYPE_CHECKING:
    import zenoh


class OdometryZenoh(ZenohEdge):
    """Publishes poses and errors; feeds impulses, pose queries and resets to the host."""

    def __init__(self, session: "zenoh.Session", keys: Keys) -> None:
        super().__init__(session)
        self.keys = keys
        self._pose = self.publisher(keys.pose, express=True)  # no batching: latency
        self._errors = self.publisher(keys.errors)

    # OdometryOutput
    def pose(self, message: Pose) -> None:
        self._pose.put(encode(message))

    def error(self, message: ErrorReport) -> None:
        self._errors.put(encode(message))

    def attach(self, host: OdometryHost, loop: asyncio.AbstractEventLoop) -> Handover:
        handover = Handover(loop)
        self.subscriber(self.keys.impulses, handover.channel("impulses", host.on_impulses, capacity=4096))
        self.queryable(self.keys.pose, handover.channel("pose?", lambda q: self._answer_pose(host, q)))
        self.queryable(self.keys.odometry_reset, handover.channel("reset?", lambda q: self._answer_reset(host, q)))
        self.token(self.keys.alive_odometry)
        return handover

    def _answer_pose(self, host: OdometryHost, query: "zenoh.Query") -> None:
        import zenoh

        with query:
            query.reply(self.keys.pose, encode(host.latest()), encoding=zenoh.Encoding.APPLICATION_JSON)

    def _answer_reset(self, host: OdometryHost, query: "zenoh.Query") -> None:
        import zenoh

        with query:
            payload = None if query.payload is None else bytes(query.payload.to_bytes())
            try:
                pose = host.on_reset(payload)
            except PayloadError as exc:
                query.reply_err(str(exc).encode())
                return
            query.reply(self.keys.odometry_reset, encode(pose), encoding=zenoh.Encoding.APPLICATION_JSON)
