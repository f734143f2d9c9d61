"""Zenoh edge of the simulator: ground truth out, faults in (docs/commands/sim.md).

The truth is published on each tick only while anyone subscribes (docs/performance.md); inputs go
through :mod:`blackmetal.runtime.edge`'s hand-over, so no work runs inside a Zenoh callback.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import msgspec

from blackmetal.runtime.edge import ZenohEdge
from blackmetal.runtime.intake import Intake
from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import Keys, PayloadError, SimFaults, encode, excerpt

from .physics import SimRobot

if TYPE_CHECKING:
    import zenoh

log = logging.getLogger("blackmetal.sim")

_dict_decoder = msgspec.json.Decoder(dict[str, Any])


def apply_fault_update(current: SimFaults, payload: bytes) -> SimFaults:
    """``current`` with the fields of a partial JSON object replaced; PayloadError if invalid."""
    data = payload.strip()
    if len(data) > 4096:
        raise PayloadError("SimFaults", "payload larger than 4096 bytes", excerpt(data))
    try:
        update = _dict_decoder.decode(data)
        return msgspec.convert({**msgspec.structs.asdict(current), **update}, SimFaults)
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise PayloadError("SimFaults", str(exc), excerpt(data)) from None


class SimZenoh(ZenohEdge):
    def __init__(self, session: "zenoh.Session", keys: Keys, robot: SimRobot, clock: Callable[[], float]) -> None:
        super().__init__(session)
        self.keys = keys
        self.robot = robot
        self.clock = clock
        self._truth = self.publisher(keys, keys.sim_truth)
        #: Someone subscribes to the truth: set by Zenoh's matching listener (on its thread: one bool, nothing else).
        self.watched = True
        self.watch_matching(self._truth, self._on_matching)
        self.routes(keys, (keys.errors,))
        self.reporter = ErrorReporter("sim", self.publish)

    def attach(self, loop: asyncio.AbstractEventLoop) -> Intake:
        intake = self.intake(loop)
        self.subscriber(self.keys.sim_faults, intake.channel("faults", self._on_faults))
        self.queryable(self.keys.sim_faults, intake.channel("faults?", self._answer_faults))
        self.queryable(self.keys.sim_truth, intake.channel("truth?", self._answer_truth))
        self.token(self.keys.alive_sim)
        return intake

    def _on_matching(self, matched: bool) -> None:
        self.watched = matched

    def tick(self) -> None:
        """The simulator's periodic step: the true pose (published if anyone watches), summaries of rate-limited reports when due."""
        now = self.clock()
        if self.watched:
            self._truth.put(self._truth_payload(now))
        self.reporter.tick(now)

    def _truth_payload(self, now: float) -> bytes:
        self.robot.advance(now)
        return encode(self.robot.pose(time.time()))

    def _on_faults(self, payload: bytes) -> None:
        try:
            self.robot.faults = apply_fault_update(self.robot.faults, payload)
            log.info("faults now %s", self.robot.faults)
        except PayloadError as exc:
            log.warning("%s", exc)
            self.reporter.report(self.keys.sim_faults, str(exc), exc.excerpt, now=self.clock())

    def _answer_faults(self, query: "zenoh.Query") -> None:
        with query:
            query.reply(self.keys.sim_faults, encode(self.robot.faults))

    def _answer_truth(self, query: "zenoh.Query") -> None:
        with query:
            query.reply(self.keys.sim_truth, self._truth_payload(self.clock()))
