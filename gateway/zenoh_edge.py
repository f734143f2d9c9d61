"""Zenoh edge of the gateway: declarations only, no logic.

Subscriber callbacks copy the payload bytes and hand them to the service's
asyncio loop with ``call_soon_threadsafe``; they never block and never call
Zenoh. Queries are handed over the same way and answered from the loop.
"""

from __future__ import annotations

import asyncio
import logging
from typing import TYPE_CHECKING

import zenoh

from schemas import ErrorReport, GatewayHealth, RobotStatus, WheelImpulses, encode

if TYPE_CHECKING:
    from .service import GatewayService

log = logging.getLogger("blackmetal.gateway")

JSON = zenoh.Encoding.APPLICATION_JSON


class GatewayZenoh:
    """Publishers are declared once; :meth:`attach` wires the inputs to a service."""

    def __init__(self, session: zenoh.Session, prefix: str) -> None:
        self.session = session
        self.prefix = prefix
        self._impulses = session.declare_publisher(
            f"{prefix}/wheels/impulses", encoding=JSON, congestion_control=zenoh.CongestionControl.DROP, express=True
        )
        self._status = session.declare_publisher(f"{prefix}/status", encoding=JSON)
        self._health = session.declare_publisher(f"{prefix}/gateway/health", encoding=JSON)
        self._errors = session.declare_publisher(f"{prefix}/errors", encoding=JSON)
        self._entities: list[object] = [self._impulses, self._status, self._health, self._errors]

    # GatewayOutput
    def impulses(self, message: WheelImpulses) -> None:
        self._impulses.put(encode(message))

    def status(self, message: RobotStatus) -> None:
        self._status.put(encode(message))

    def health(self, message: GatewayHealth) -> None:
        self._health.put(encode(message))

    def error(self, message: ErrorReport) -> None:
        log.warning("error on %s: %s", message.key, message.reason)
        self._errors.put(encode(message))

    def attach(self, service: "GatewayService", loop: asyncio.AbstractEventLoop) -> None:
        """Declare the subscribers, queryable and liveliness token that feed ``service``."""
        prefix = self.prefix

        def handover(handler):  # type: ignore[no-untyped-def]
            def callback(sample: zenoh.Sample) -> None:
                try:
                    payload = sample.payload.to_bytes()
                except Exception:  # never let anything escape into Zenoh's thread
                    payload = b""
                loop.call_soon_threadsafe(handler, payload)

            return callback

        def on_health_query(query: zenoh.Query) -> None:
            loop.call_soon_threadsafe(self._answer_health, service, query)

        self._entities += [
            self.session.declare_subscriber(f"{prefix}/cmd_vel", handover(service.on_cmd_vel)),
            self.session.declare_subscriber(f"{prefix}/estop", handover(service.on_estop)),
            self.session.declare_queryable(f"{prefix}/gateway/health", on_health_query),
            self.session.liveliness().declare_token(f"{prefix}/alive/gateway"),
        ]

    def _answer_health(self, service: "GatewayService", query: zenoh.Query) -> None:
        with query:
            query.reply(f"{self.prefix}/gateway/health", encode(service.health()), encoding=JSON)

    def close(self) -> None:
        for entity in reversed(self._entities):
            try:
                entity.undeclare()  # type: ignore[attr-defined]
            except Exception:
                pass
        self._entities.clear()
