"""Zenoh edge of the simulator: ground truth out, faults in.

Publishes the true pose on ``<prefix>/sim/truth`` at a fixed rate, answers
``get`` on ``<prefix>/sim/truth`` and ``<prefix>/sim/faults``, and takes
partial fault settings put on ``<prefix>/sim/faults``. Zenoh's handlers are
FIFO channels drained from the simulator's own loop, so no work runs inside
a Zenoh callback.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

import msgspec
import zenoh

from schemas import ErrorReport, PayloadError, SimFaults, encode, excerpt, to_bytes

from .robot import SimRobot

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


class SimZenohEdge:
    """Declares the simulator's publishers, subscriber and queryables on an open session."""

    def __init__(self, session: zenoh.Session, prefix: str, robot: SimRobot, clock: Callable[[], float]) -> None:
        self.robot = robot
        self.clock = clock
        self.prefix = prefix
        json_enc = zenoh.Encoding.APPLICATION_JSON
        self._truth = session.declare_publisher(f"{prefix}/sim/truth", encoding=json_enc)
        self._errors = session.declare_publisher(f"{prefix}/errors", encoding=json_enc)
        self._faults_sub = session.declare_subscriber(f"{prefix}/sim/faults")
        self._faults_q = session.declare_queryable(f"{prefix}/sim/faults")
        self._truth_q = session.declare_queryable(f"{prefix}/sim/truth")
        self._token = session.liveliness().declare_token(f"{prefix}/alive/sim")
        self.published = 0

    def tick(self) -> None:
        """Publish the truth once and serve whatever arrived since the last tick."""
        self.robot.advance(self.clock())
        payload = encode(self.robot.pose(time.time()))
        self._truth.put(payload)
        self.published += 1
        while (sample := self._faults_sub.try_recv()) is not None:
            self._on_faults(to_bytes(sample.payload))
        while (query := self._faults_q.try_recv()) is not None:
            with query:
                query.reply(f"{self.prefix}/sim/faults", encode(self.robot.faults))
        while (query := self._truth_q.try_recv()) is not None:
            with query:
                query.reply(f"{self.prefix}/sim/truth", payload)

    def _on_faults(self, payload: bytes) -> None:
        try:
            self.robot.faults = apply_fault_update(self.robot.faults, payload)
            log.info("faults now %s", self.robot.faults)
        except PayloadError as exc:
            log.warning("%s", exc)
            report = ErrorReport(
                stamp=time.time(), source="sim", key=f"{self.prefix}/sim/faults", reason=str(exc), excerpt=exc.excerpt
            )
            self._errors.put(encode(report))

    def close(self) -> None:
        for entity in (self._token, self._faults_sub, self._faults_q, self._truth_q, self._truth, self._errors):
            try:
                entity.undeclare()
            except Exception:  # already undeclared by a closing session
                pass
