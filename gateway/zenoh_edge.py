"""Zenoh edge of the gateway: declarations only, no logic.

Inputs go through the one intake of :mod:`blackmetal.runtime.intake`: the
callbacks copy the payload and the service's loop runs the handlers. Each
input has its own bounded intake, so a flood of one can neither delay,
mask nor expire another:

* the e-stop (``estop`` and ``estop/release``): one latest-state slot, ahead
  of everything; an ON is kept until handled even if newer samples follow;
  a storm changes over to Zenoh's ring buffer like any flooded input;
* each configured command source and each configured lock: its own
  subscriber (a flooded one changes over to Zenoh's ring buffer alone) and
  its own latest slot; what a newer command supersedes is counted against
  its source in health;
* names nobody configured share one small queue and create no state per
  name: they are refused and reported, rate-limited per key family.

Health queries are answered from the loop. Commands and e-stops are taken
directly on the Zenoh thread that delivers them when their robot's core is
free (the intake's ``direct``, :mod:`blackmetal.gateway.direct`), in a fleet
host too: each robot has its own core lock, so one robot's loop work never
holds another's e-stop back.
"""

from __future__ import annotations

import asyncio
import functools
from collections.abc import Callable
from typing import TYPE_CHECKING

import msgspec

from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.edge import ZenohEdge
from blackmetal.runtime.flood import newest
from blackmetal.runtime.intake import Intake
from blackmetal.runtime.zenoh_entities import Item
from blackmetal.schemas import (
    DriverChange,
    ErrorReport,
    GatewayHealth,
    GatewayParams,
    Keys,
    RobotStatus,
    WheelImpulses,
    encode,
    payload_bytes,
)

from .arbiter import DEFAULT_SOURCE
from .estop import read_estop

if TYPE_CHECKING:
    import zenoh

    from .host import GatewayHost

#: Inputs on names nobody configured, waiting to be refused: a flood of new names keeps the newest few.
UNKNOWN_NAMES_CAPACITY = 8


def _as_name(name: str, put: Callable[[tuple[str, bytes]], None]) -> Callable[[tuple[str, bytes]], None]:
    """A put that hands ``(name, payload)`` over, whatever key chunk the sample came on."""
    return lambda item: put((name, item[1]))


def _engages(item: tuple[bool, bytes]) -> bool:
    """An e-stop sample that engages: it is latched in the intake until handled (see Channel)."""
    return read_estop(item[1])[0]


def _estop_batch(batch: list[Item]) -> list[Item]:
    """What a storm's pump hands over of a batch of e-stop samples: the first that engages, if the newest does not, and the newest."""
    last = batch[-1]
    if read_estop(last[1])[0]:
        return [last]
    first_on = next((item for item in batch if read_estop(item[1])[0]), None)
    return [last] if first_on is None else [first_on, last]


class GatewayZenoh(ZenohEdge):
    """Publishers are declared at once; :meth:`attach` wires the inputs to a service."""

    def __init__(self, session: "zenoh.Session", keys: Keys, *, burst: PutBurst | None = None) -> None:
        """``burst`` (a fleet host, many robots on one session): impulses go out batched, not express, held to the end of
        the loop's turn and put back to back with the other robots' (:mod:`blackmetal.runtime.burst`).

        One robot: express, the lowest latency. A fleet: an express put per impulse sample is a write of
        its own and a wake of Zenoh's tx thread each, which at 100 robots x 50 Hz was a quarter of the
        gateway's Python time and kept it from polling at 50 Hz (35 Hz; batched: 47 Hz, router CPU per
        message halved). Zenoh still sends at once while the link is idle: hence the burst.
        """
        super().__init__(session)
        self.keys = keys
        self._burst = burst
        self._impulses = self.publisher(keys.impulses, express=burst is None)
        self._status = self.publisher(keys.status)
        self._health = self.publisher(keys.health)
        self._errors = self.publisher(keys.errors)
        self._driver = self.publisher(keys.driver)
        self._params = self.publisher(keys.params)

    # GatewayOutput
    def impulses(self, message: WheelImpulses) -> None:
        if self._burst is not None:
            self._burst.put(self._impulses, encode(message))
        else:
            self._impulses.put(encode(message))

    def status(self, message: RobotStatus) -> None:
        self._status.put(encode(message))

    def health(self, message: GatewayHealth) -> None:
        self._health.put(encode(message))

    def error(self, message: ErrorReport) -> None:
        self._errors.put(encode(message))

    def driver(self, message: DriverChange) -> None:
        self._driver.put(encode(message))

    def params(self, message: GatewayParams) -> None:
        self._params.put(encode(message))

    def attach(self, service: "GatewayHost", loop: asyncio.AbstractEventLoop) -> Intake:
        """Declare the subscribers, queryable and liveliness token that feed ``service``."""
        keys = self.keys
        arbiter = service.core.arbiter
        # a bug in handling one input fails this robot's host, visibly; what the inputs produced is published after each drain
        intake = self.intake(loop, on_error=service.fail, lock=service.lock, after_drain=service.publish)
        estop = intake.channel("estop", service.on_estop_input, latest=True, latch=_engages, priority=2, direct=service.estop_direct)
        flood = service.on_input_flood
        # guarded too: a storm of e-stop samples must not keep Zenoh's thread in Python while its final ON waits behind
        # them. One subscriber per key, exact: one on estop/** matching both keys delayed a storm's final ON by 0.2-0.3 s
        # inside Zenoh (1.10), where two exact ones took 2-3 ms. Samples of the two keys keep their order while they come
        # through callbacks (one Zenoh thread); while both keys flood, each has its own pump, and a release may be taken
        # a turn after an ON put after it (see docs/safety.md).
        self.guarded(keys.estop, lambda item: estop((False, item[1])), intake, flood, pick=_estop_batch)
        self.guarded(keys.estop_release, lambda item: estop((True, item[1])), intake, flood, pick=_estop_batch)
        sources: dict[str, Callable[[tuple[str, bytes]], None]] = {}
        for name in arbiter.names:
            put = intake.channel(
                f"cmd_vel/{name}",
                service.on_source_cmd_vel,
                latest=True,
                priority=1,
                direct=service.cmd_vel_direct,
                on_dropped=functools.partial(service.on_superseded, name),
            )
            sources[name] = put
            self.guarded(keys.cmd_vel_of(name), _as_name(name, put), intake, flood, pick=newest)
        unknown_source = intake.channel("cmd_vel/?", service.on_source_cmd_vel, capacity=UNKNOWN_NAMES_CAPACITY)
        default = sources.get(DEFAULT_SOURCE)

        def any_source(item: tuple[str, bytes]) -> None:
            """``<prefix>/cmd_vel/<name>``: configured names come through their own subscriber (``cmd_vel/default`` here)."""
            name = item[0]
            if name == DEFAULT_SOURCE and default is not None:
                default(item)
            elif name not in sources:
                unknown_source(item)

        self.guarded(keys.any_cmd_vel_source, any_source, intake, flood)
        locks: set[str] = set()
        for name in arbiter.lock_names:
            put_lock = intake.channel(f"lock/{name}", service.on_named_lock, latest=True, priority=1)
            locks.add(name)
            self.guarded(keys.lock_of(name), _as_name(name, put_lock), intake, flood, pick=newest)
        unknown_lock = intake.channel("lock/?", service.on_named_lock, capacity=UNKNOWN_NAMES_CAPACITY)
        self.guarded(keys.any_lock, lambda item: None if item[0] in locks else unknown_lock(item), intake, flood)
        self.queryable(keys.health, intake.channel("health?", lambda q: self._answer_health(service, q), capacity=16))
        self.queryable(
            keys.errors, intake.channel("errors?", lambda q: self.answer_recent(q, keys.errors, service.recent_errors()), capacity=16)
        )
        self.queryable(keys.params, intake.channel("params?", lambda q: self._answer(q, keys.params, service.params()), capacity=16))
        self.queryable(keys.params_set, intake.channel("params set?", lambda q: self._answer_set(service, q), capacity=16))
        # every gateway publishes its health once a second: another run's report on our key is a second gateway
        self.subscriber(keys.health, intake.channel("health seen", service.on_health_seen, capacity=16))
        self.token(keys.alive_gateway)
        return intake

    def _answer_health(self, service: "GatewayHost", query: "zenoh.Query") -> None:
        self._answer(query, self.keys.health, service.health())

    def _answer_set(self, service: "GatewayHost", query: "zenoh.Query") -> None:
        """Set parameters; a payload that is no ParamsSet is answered with an error reply saying why."""
        reply = service.set_params(payload_bytes(query))
        if isinstance(reply, str):
            with query:
                query.reply_err(reply)
        else:
            self._answer(query, self.keys.params_set, reply)

    @staticmethod
    def _answer(query: "zenoh.Query", key: str, message: msgspec.Struct) -> None:
        import zenoh

        with query:
            query.reply(key, encode(message), encoding=zenoh.Encoding.APPLICATION_JSON)
