"""Zenoh edge of the gateway: declarations only, no logic.

Its inputs are one table (:meth:`GatewayZenoh.attach`): each key, its intake
channel (bounded, so a flood of one input can neither delay, mask nor expire
another), the core method the driver calls, and how a sample is named or
decoded where it enters; its outputs go to the key the key space gives their
type. The channels, their priorities and the direct take: ``docs/threads.md``.
"""

from __future__ import annotations

import asyncio
import functools
from typing import TYPE_CHECKING, Any

import msgspec

from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.edge import ZenohEdge
from blackmetal.runtime.flood import newest
from blackmetal.runtime.intake import Intake
from blackmetal.schemas import Keys, encode, payload_bytes

from .arbiter import DEFAULT_SOURCE
from .estop import EStopInput, read_estop

if TYPE_CHECKING:
    import zenoh

    from .host import GatewayHost

#: Inputs on names nobody configured, waiting to be refused: a flood of new names keeps the newest few.
UNKNOWN_NAMES_CAPACITY = 8
#: Queries waiting for the loop, per queryable.
QUERIES_CAPACITY = 16


def _engages(item: EStopInput) -> bool:
    """An e-stop sample that engages: it is latched in the intake until handled (see Channel)."""
    return item.engaged


def _estop_batch(batch: list[EStopInput]) -> list[EStopInput]:
    """What a storm's pump hands over of a batch of e-stop samples: the first that engages, if the newest does not, and the newest."""
    last = batch[-1]
    if last.engaged:
        return [last]
    first_on = next((item for item in batch if item.engaged), None)
    return [last] if first_on is None else [first_on, last]


class GatewayZenoh(ZenohEdge):
    """Publishers are declared at once; :meth:`attach` wires the inputs to a service."""

    def __init__(self, session: "zenoh.Session", keys: Keys, *, burst: PutBurst | None = None) -> None:
        """``burst`` (a fleet host): impulses batched, not express, and put back to back with the other robots'.

        An express put per impulse wakes Zenoh's tx thread each: at 100 robots x 50 Hz a quarter of the gateway's
        Python time, polling at 35 Hz instead of 47 (``docs/threads.md``, PutBurst).
        """
        super().__init__(session)
        self.keys = keys
        self.fleet = burst is not None
        published = (keys.impulses, keys.wheels_position, keys.status, keys.health, keys.errors, keys.driver, keys.params)
        self.routes(keys, published, fast=keys.impulses, burst=burst)

    def attach(self, service: "GatewayHost", loop: asyncio.AbstractEventLoop) -> Intake:
        """Declare the subscribers, queryables and liveliness token that feed ``service``, as the table below says."""
        keys, core, driver = self.keys, service.core, service.driver
        sources, locks = core.arbiter.names, core.arbiter.lock_names
        # a bug in handling one input fails this robot's host, visibly; what the inputs produced is published after each drain
        intake = self.intake(loop, on_error=driver.fail, lock=driver.lock, after_drain=driver.publish)
        on = driver.handler
        estop = intake.channel(
            "estop",
            on(core.on_estop, unpack=False),
            latest=True,
            latch=_engages,
            priority=2,
            direct=service.direct(core.on_estop, unpack=False),
        )
        cmd_vel = {
            name: intake.channel(
                f"cmd_vel/{name}",
                on(core.on_cmd_vel),
                latest=True,
                priority=1,
                direct=service.direct(core.on_cmd_vel),
                on_dropped=functools.partial(driver.run_locked, core.on_superseded, name),
            )
            for name in sources
        }
        lock = {name: intake.channel(f"lock/{name}", on(core.on_lock), latest=True, priority=1) for name in locks}
        unknown_source = intake.channel("cmd_vel/?", on(core.on_cmd_vel), capacity=UNKNOWN_NAMES_CAPACITY)
        unknown_lock = intake.channel("lock/?", on(core.on_lock), capacity=UNKNOWN_NAMES_CAPACITY)
        release, engage = functools.partial(read_estop, release_key=True), functools.partial(read_estop, release_key=False)
        # Every subscriber a client may flood, one per key, exact: one on estop/** matching both keys delayed a storm's
        # final ON by 0.2-0.3 s inside Zenoh (1.10), where two exact ones took 2-3 ms. Samples of the two e-stop keys keep
        # their order while they come through callbacks (one Zenoh thread); while both keys flood, each has its own pump,
        # and a release may be taken a turn after an ON put after it (see docs/safety.md).
        #   key                                 channel                      item: decoded once, here
        guarded: list[tuple[str, Any, dict[str, Any]]] = [
            (keys.estop, estop, {"decode": engage, "pick": _estop_batch}),
            (keys.estop_release, estop, {"decode": release, "pick": _estop_batch}),
            *((keys.cmd_vel_of(name), cmd_vel[name], {"name": name, "pick": newest}) for name in sources),
            *((f"{keys.cmd_vel}/{DEFAULT_SOURCE}", cmd_vel[name], {"pick": newest}) for name in sources if name == DEFAULT_SOURCE),
            (keys.any_cmd_vel_source, unknown_source, {"skip": frozenset(sources)}),
            *((keys.lock_of(name), lock[name], {"pick": newest}) for name in locks),
            (keys.any_lock, unknown_lock, {"skip": frozenset(locks)}),
        ]
        flood = functools.partial(driver.take, core.note_input)
        for key, put, options in guarded:
            self.guarded(key, put, intake, flood, indirect=self.fleet, **options)
        now = driver.clock
        move = on(core.on_wheel_move, unpack=False)
        #   channel        key              answered on the loop, under the core lock, with
        queries = [
            ("health?", keys.health, lambda q: self._answer(q, keys.health, core.health(now()))),
            ("errors?", keys.errors, lambda q: self.answer_recent(q, keys.errors, list(core.reporter.recent))),
            ("params?", keys.params, lambda q: self._answer(q, keys.params, core.params_now())),
            ("params set?", keys.params_set, lambda q: self._answer_set(q, on(core.on_params_set, unpack=False))),
            ("wheels move?", keys.wheels_move, lambda q: self._answer(q, keys.wheels_move, move(payload_bytes(q)))),
        ]
        for name, key, answer in queries:
            self.queryable(key, intake.channel(name, answer, capacity=QUERIES_CAPACITY))
        # every gateway publishes its health once a second: another run's report on our key is a second gateway
        self.subscriber(keys.health, intake.channel("health seen", on(core.on_health_seen, unpack=False), capacity=QUERIES_CAPACITY))
        self.token(keys.alive_gateway)
        return intake

    def _answer_set(self, query: "zenoh.Query", set_params: Any) -> None:
        """Set parameters; a payload that is no ParamsSet is answered with an error reply saying why."""
        reply = set_params(payload_bytes(query))
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
