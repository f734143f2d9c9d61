"""Zenoh edge of the gateway: declarations only, no logic.

Inputs go through the one hand-over of :mod:`blackmetal.runtime.edge`: the
callbacks copy the payload and the service's loop runs the handlers, the
e-stop channel ahead of everything else; each channel is bounded, so a
flood of commands can neither grow memory nor delay an e-stop. Health queries are answered from
the loop. A single robot's gateway takes commands and e-stops directly on
the Zenoh thread that delivers them when its core is free (the hand-over's
``direct``); a fleet host leaves them to its loop, so a hundred robots'
commands never keep Zenoh's thread in Python.
"""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING

from blackmetal.runtime.edge import Handover, ZenohEdge
from schemas import ErrorReport, GatewayHealth, Keys, RobotStatus, WheelImpulses, encode

from .arbiter import DEFAULT_SOURCE

if TYPE_CHECKING:
    import zenoh

    from .host import GatewayHost


class GatewayZenoh(ZenohEdge):
    """Publishers are declared at once; :meth:`attach` wires the inputs to a service."""

    def __init__(self, session: "zenoh.Session", keys: Keys, *, batched: bool = False) -> None:
        """``batched``: impulses go out batched, not express (a fleet host, many robots on one session).

        One robot: express, the lowest latency. A fleet: an express put per impulse sample is a write of
        its own and a wake of Zenoh's tx thread each, which at 100 robots x 50 Hz was a quarter of the
        gateway's Python time and kept it from polling at 50 Hz (35 Hz; batched: 47 Hz, router CPU per
        message halved). Zenoh still sends at once while the link is idle. A fleet also takes every input
        on its loop (no direct takes).
        """
        super().__init__(session)
        self.keys = keys
        self.direct = not batched
        self._impulses = self.publisher(keys.impulses, express=not batched, drop_when_congested=True)
        self._status = self.publisher(keys.status)
        self._health = self.publisher(keys.health)
        self._errors = self.publisher(keys.errors)

    # GatewayOutput
    def impulses(self, message: WheelImpulses) -> None:
        self._impulses.put(encode(message))

    def status(self, message: RobotStatus) -> None:
        self._status.put(encode(message))

    def health(self, message: GatewayHealth) -> None:
        self._health.put(encode(message))

    def error(self, message: ErrorReport) -> None:
        self._errors.put(encode(message))

    def attach(self, service: "GatewayHost", loop: asyncio.AbstractEventLoop) -> Handover:
        """Declare the subscribers, queryable and liveliness token that feed ``service``."""
        # a bug in handling one input fails this robot's host, visibly
        handover = Handover(loop, on_error=service.fail, lock=service.lock if self.direct else None)
        direct = self.direct
        # bounded: a flood keeps the newest 64 (the governor acts on the latest anyway); e-stop first, always
        estop = handover.channel("estop", service.on_estop, capacity=64, priority=2, direct=service.take_estop_now if direct else None)
        self.subscriber(self.keys.estop, estop)
        # commands and locks a client may flood: while one floods, it waits in Zenoh's ring buffer and reaches
        # the loop at its pace, so it can neither grow memory nor hold up the e-stop; plain cmd_vel is the source 'default'
        commands = handover.channel(
            "cmd_vel", service.on_source_cmd_vel, capacity=64, priority=1, direct=service.take_cmd_vel_now if direct else None
        )
        flood = service.on_input_flood
        self.guarded(self.keys.cmd_vel, lambda item: commands((DEFAULT_SOURCE, item[1])), handover, flood)
        self.guarded(self.keys.any_cmd_vel_source, commands, handover, flood)
        locks = handover.channel("lock/*", service.on_named_lock, capacity=64, priority=1)
        self.guarded(self.keys.any_lock, locks, handover, flood)
        self.queryable(self.keys.health, handover.channel("health?", lambda q: self._answer_health(service, q), capacity=16))
        # every gateway publishes its health once a second: another run's report on our key is a second gateway
        self.subscriber(self.keys.health, handover.channel("health seen", service.on_health_seen, capacity=16))
        self.token(self.keys.alive_gateway)
        return handover

    def _answer_health(self, service: "GatewayHost", query: "zenoh.Query") -> None:
        import zenoh

        with query:
            query.reply(self.keys.health, encode(service.health()), encoding=zenoh.Encoding.APPLICATION_JSON)
