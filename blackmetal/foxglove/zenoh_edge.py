"""Zenoh edge of the Foxglove view: declarations only; payloads and replies handed over to the view's loop.

It subscribes to every key the view shows (:meth:`LiveView.handlers`),
publishes what the view's clients command (``<prefix>/cmd_vel/foxglove``,
``<prefix>/estop``) and its error reports, and asks the gateway's health and
the odometry's reset for the services; replies come back through the same
hand-over, never handled on a Zenoh thread.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

from blackmetal.runtime.edge import ZenohEdge
from blackmetal.runtime.intake import Intake
from blackmetal.schemas import ErrorReport, Keys, encode, payload_bytes

from .core import COMMAND_SOURCE, LiveView

if TYPE_CHECKING:
    import zenoh


class Answers(Protocol):
    """Who takes the gateway's health and the odometry's reset replies: the host, or a fleet's robot's port."""

    def on_health(self, payload: bytes) -> None: ...
    def on_reset_reply(self, reply: tuple[int, bytes | None, bytes | None]) -> None: ...


def _error_bytes(reply: "zenoh.Reply") -> bytes:
    try:
        return bytes(reply.err.payload.to_bytes()) if reply.err is not None else b""
    except Exception:
        return b""


class FoxgloveZenoh(ZenohEdge):
    """The view's Zenoh side: subscriptions for what it shows, publishers and queries for what its clients do."""

    def __init__(self, session: "zenoh.Session", keys: Keys, query_timeout: float = 2.0) -> None:
        super().__init__(session)
        self.keys = keys
        self.query_timeout = query_timeout
        self._publishers = {
            keys.cmd_vel_of(COMMAND_SOURCE): self.publisher(keys.cmd_vel_of(COMMAND_SOURCE), express=True),
            keys.estop: self.publisher(keys.estop, express=True),  # blocking congestion control: a stop is never dropped
        }
        self._errors = self.publisher(keys.errors)
        self._health_reply: Callable[[bytes], None] = lambda payload: None
        self._reset_reply: Callable[[tuple[int, bytes | None, bytes | None]], None] = lambda reply: None

    def attach(
        self,
        view: LiveView,
        host: Answers,
        loop: asyncio.AbstractEventLoop,
        handlers: dict[str, Callable[[bytes], None]] | None = None,
        on_error: Callable[[BaseException], None] | None = None,
    ) -> Intake:
        """Subscribe ``handlers`` (default: the view's) on the loop; ``on_error`` takes what a handler raised (None: the loop's handler)."""
        handover = Intake(loop, on_error)
        handlers = dict(handlers if handlers is not None else view.handlers())
        show_health = handlers[self.keys.health]

        def on_health(payload: bytes) -> None:
            show_health(payload)
            host.on_health(payload)

        handlers[self.keys.health] = on_health
        for key, handler in handlers.items():
            self.subscriber(key, handover.channel(key, handler, capacity=512))
        self._health_reply = handover.channel("health?", host.on_health, capacity=64)
        self._reset_reply = handover.channel("reset?", host.on_reset_reply, capacity=64)  # replies, then the end, in order
        return handover

    # ZenohSide
    def command(self, key: str, payload: bytes) -> None:
        self._publishers[key].put(payload)

    def error(self, message: ErrorReport) -> None:
        self._errors.put(encode(message))

    def ask_health(self) -> None:
        import zenoh

        put = self._health_reply

        def on_reply(reply: "zenoh.Reply") -> None:
            if reply.ok is not None:
                put(payload_bytes(reply.ok))

        self.session.get(self.keys.health, zenoh.handlers.Callback(on_reply), timeout=self.query_timeout)

    def ask_reset(self, call: int, payload: bytes) -> None:
        import zenoh

        put = self._reset_reply

        def on_reply(reply: "zenoh.Reply") -> None:
            put((call, payload_bytes(reply.ok), None) if reply.ok is not None else (call, None, _error_bytes(reply)))

        def on_end() -> None:
            put((call, None, None))

        self.session.get(self.keys.odometry_reset, zenoh.handlers.Callback(on_reply, on_end), payload=payload, timeout=self.query_timeout)
