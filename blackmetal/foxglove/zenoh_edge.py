"""Zenoh edge of the Foxglove view: declarations only; payloads and replies handed over to the view's loop.

A robot's keys are subscribed **only while someone watches** a channel they feed (:meth:`FoxgloveZenoh.want`),
each into a ring of Zenoh's own that the loop drains every :data:`DRAIN_PERIOD_S`: no Python runs per sample
(docs/foxglove.md, "Only what is watched"). Commands and the e-stop block rather than drop; error reports drop.
Replies come back through the same hand-over, never handled on a Zenoh thread.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING, Any, Protocol

from blackmetal.runtime.edge import ZenohEdge
from blackmetal.runtime.intake import Intake
from blackmetal.runtime.zenoh_entities import undeclare
from blackmetal.schemas import ErrorReport, Keys, encode, payload_bytes

from .naming import COMMAND_SOURCE
from .watch import Watch

if TYPE_CHECKING:
    import zenoh

Reply = tuple[int, bytes | None, bytes | None]

#: Samples a watched key's ring keeps between two drains (a pose at 50 Hz brings one a drain).
RING = 64
#: How often the loop takes what the watched keys brought (s): the view's refresh, 50 Hz.
DRAIN_PERIOD_S = 0.02


class Wired(Protocol):
    """What the host, the parameters and the Zenoh edges ask of :class:`~.fleet.Wiring` (here, below all three)."""

    watch: Watch

    def subscribed(self, topic: str) -> None:
        """A client subscribed to ``topic`` (what is sent once, the URDF, goes to it now)."""

    def watch_changed(self) -> None:
        """The watched topics changed: subscribe to the keys they need, and only those."""

    def ask_params(self, robot_id: str) -> None: ...
    def set_params(self, robot_id: str, call: int, payload: bytes) -> None: ...
    def report(self, robot_id: str | None, topic: str, reason: str, text: str, now: float) -> None: ...
    def on_health(self, robot_id: str, payload: bytes) -> None: ...
    def on_reset_reply(self, robot_id: str, reply: Reply) -> None: ...
    def on_nav_reply(self, robot_id: str, reply: Reply) -> None: ...
    def on_params(self, robot_id: str, payload: bytes) -> None: ...
    def on_params_reply(self, robot_id: str, reply: Reply) -> None: ...
    def on_bug(self, robot_id: str, exc: BaseException) -> None: ...


class NoEdge:
    """A robot's edge before the Zenoh session opens and after it closes: what is sent goes nowhere, nothing is followed."""

    declared: frozenset[str] = frozenset()

    def command(self, key: str, payload: bytes) -> None: ...
    def error(self, message: ErrorReport) -> None: ...
    def ask_health(self) -> None: ...
    def ask_params(self) -> None: ...
    def ask_reset(self, call: int, payload: bytes) -> None: ...
    def ask_nav(self, key: str, call: int, payload: bytes) -> None: ...
    def want(self, keys: set[str]) -> None: ...
    def peek(self, on: bool) -> None: ...
    def latest_pose(self) -> bytes | None: ...

    def drain(self) -> int:
        return 0


#: The edge of every robot while no session is open.
NO_EDGE = NoEdge()


class FoxgloveZenoh(ZenohEdge):
    """One robot's Zenoh side of the view: subscriptions for what is watched, publishers and queries for what clients do."""

    def __init__(self, session: "zenoh.Session", keys: Keys, query_timeout: float = 2.0) -> None:
        super().__init__(session)
        self.keys = keys
        self.query_timeout = query_timeout
        # blocking congestion control and express: a command or a stop is never dropped, never waits for a batch
        controls = (keys.cmd_vel_of(COMMAND_SOURCE), keys.estop, keys.estop_release)
        self._publishers = {key: self.publisher(keys, key, express=True) for key in controls}
        self._errors = self.publisher(keys, keys.errors)  # telemetry: never held behind a dead link
        self._handlers: dict[str, Callable[[bytes], None]] = {}
        self._on_error: Callable[[BaseException], None] | None = None
        self._declared: dict[str, Any] = {}
        self._peek: Any = None
        self._peeked: bytes | None = None
        self._map_pose: Callable[[bytes], None] | None = None

    def attach(
        self,
        robot_id: str,
        handlers: dict[str, Callable[[bytes], None]],
        host: Wired,
        loop: asyncio.AbstractEventLoop,
        presence: Callable[[bool], None] | None = None,
    ) -> Intake:
        """Hand-over channels for ``handlers`` (declared by :meth:`want`), the gateway's parameters and, with
        ``presence``, its liveliness token; what a handler raises goes to ``host.on_bug``."""
        on_error = partial(host.on_bug, robot_id)
        handover = self.intake(loop, on_error=on_error)
        handlers = dict(handlers)
        show_health = handlers[self.keys.health]

        def on_health(payload: bytes) -> None:
            show_health(payload)
            host.on_health(robot_id, payload)

        handlers[self.keys.health] = on_health
        self._handlers, self._on_error = handlers, on_error
        self._params = handover.channel("params", partial(host.on_params, robot_id), capacity=16)  # published and asked for alike
        self.subscriber(self.keys.params, self._params)
        if presence is not None:
            put = handover.channel("alive", presence, capacity=64)

            def on_token(sample: "zenoh.Sample") -> None:
                import zenoh

                put(sample.kind == zenoh.SampleKind.PUT)

            token = self.session.liveliness().declare_subscriber(self.keys.alive_gateway, on_token, history=True)
            self._entities.append(token)
        self._health_reply = handover.channel("health?", partial(host.on_health, robot_id), capacity=64)
        # replies, then the end, in order
        self._reset_reply = handover.channel("reset?", partial(host.on_reset_reply, robot_id), capacity=64)
        self._set_reply = handover.channel("params set?", partial(host.on_params_reply, robot_id), capacity=64)
        self._nav_reply = handover.channel("nav?", partial(host.on_nav_reply, robot_id), capacity=64)
        # the map frame is published when it changes: a view that starts following it asks for it too
        map_pose = handlers.get(self.keys.nav_map_pose)
        self._map_pose = handover.channel("map pose?", map_pose, capacity=16) if map_pose is not None else None
        return handover

    def want(self, keys: set[str]) -> None:
        """Subscribe to exactly these of the view's keys, each into its ring."""
        import zenoh

        for key in [key for key in self._declared if key not in keys]:
            undeclare(self._declared.pop(key))
        for key in sorted(keys):
            if key in self._handlers and key not in self._declared:
                self._declared[key] = self.session.declare_subscriber(key, zenoh.handlers.RingChannel(RING))
                if key == self.keys.nav_map_pose and self._map_pose is not None:
                    self._get(key, self._map_pose)

    def drain(self) -> int:
        """On the loop: the rings' samples to their handlers, oldest first; how many. A handler that raises goes to
        ``on_error`` and the next sample goes on."""
        taken = 0
        for key, subscriber in list(self._declared.items()):
            handler = self._handlers[key]
            while (sample := subscriber.try_recv()) is not None:
                taken += 1
                try:
                    handler(payload_bytes(sample))
                except Exception as exc:
                    if self._on_error is None:
                        raise
                    self._on_error(exc)
        return taken

    @property
    def declared(self) -> set[str]:
        return set(self._declared)

    def peek(self, on: bool) -> None:
        """Keep (or stop keeping) the robot's latest pose in a one-slot ring, for :meth:`latest_pose`."""
        import zenoh

        if on and self._peek is None:
            self._peek = self.session.declare_subscriber(self.keys.pose, zenoh.handlers.RingChannel(1))
        elif not on and self._peek is not None:
            undeclare(self._peek)
            self._peek, self._peeked = None, None

    def latest_pose(self) -> bytes | None:
        if self._peek is not None:
            sample = self._peek.try_recv()
            if sample is not None:
                self._peeked = payload_bytes(sample)
        return self._peeked

    def close(self) -> None:
        for key in list(self._declared):
            undeclare(self._declared.pop(key))
        self.peek(False)
        super().close()

    def command(self, key: str, payload: bytes) -> None:
        self._publishers[key].put(payload)

    def error(self, message: ErrorReport) -> None:
        self._errors.put(encode(message))

    def _get(self, key: str, put: Callable[[bytes], None], payload: bytes | None = None) -> None:
        import zenoh

        def on_reply(reply: "zenoh.Reply") -> None:
            if reply.ok is not None:
                put(payload_bytes(reply.ok))

        self.session.get(key, zenoh.handlers.Callback(on_reply), payload=payload, timeout=self.query_timeout)

    def ask_health(self) -> None:
        self._get(self.keys.health, self._health_reply)

    def ask_params(self) -> None:
        self._get(self.keys.params, self._params)

    def _ask(self, key: str, put: Callable[[Reply], None], call: int, payload: bytes | None) -> None:
        """A get whose replies (``(call, ok, None)`` / ``(call, None, err)``) and end (``(call, None, None)``) go to ``put`` in order."""
        import zenoh

        def on_reply(reply: "zenoh.Reply") -> None:
            if reply.ok is not None:
                return put((call, payload_bytes(reply.ok), None))
            try:
                err = bytes(reply.err.payload.to_bytes()) if reply.err is not None else b""
            except Exception:
                err = b""
            put((call, None, err))

        def on_end() -> None:
            put((call, None, None))

        self.session.get(key, zenoh.handlers.Callback(on_reply, on_end), payload=payload, timeout=self.query_timeout)

    def ask_reset(self, call: int, payload: bytes) -> None:
        self._ask(self.keys.odometry_reset, self._reset_reply, call, payload)

    def ask_nav(self, key: str, call: int, payload: bytes) -> None:
        """A goal or a set-pose for the navigation service; its answer goes to ``host.on_nav_reply``."""
        self._ask(key, self._nav_reply, call, payload or None)

    def set_params(self, call: int, payload: bytes) -> None:
        self._ask(self.keys.params_set, self._set_reply, call, payload)
