"""Zenoh edge of the navigation service: its input table and its outputs, declarations only.

Inputs reach the host on the service's loop through one intake (a fleet's poses through a ring each, drained by the
loop); liveliness subscribers ask for history, so a gateway or an odometry alive before nav started is seen at once
(any start order), and a gateway that appears is asked for its health and its parameters (published each second and
only on a change). Outputs are routed by type (:meth:`ZenohEdge.routes`): ``Twist`` to ``cmd_vel/nav`` (a command:
never dropped, express), ``NavFeedback``, ``MapPose``, ``GatewayParams`` (``nav/params``) and ``ErrorReport``.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import deque
from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING

import msgspec

from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.edge import ZenohEdge
from blackmetal.runtime.intake import Intake
from blackmetal.schemas import Keys, NavFeedback, PayloadError, Sources, Twist, encode, payload_bytes

from .host import NavHost

if TYPE_CHECKING:
    import zenoh

#: A fleet robot's poses wait in a Zenoh ring of this many for :meth:`NavZenoh.drain` (which takes the newest).
RING = 4
#: While its navigation drives nothing, a fleet robot's poses are taken at most this often (s), not at every drain: no
#: goal needs them sooner (a goal or a move takes the newest first). The last two are taken, so the core still sees the
#: poses' own period between them; the pause itself (longer than 0.2 s) the core's period estimate leaves out.
IDLE_DRAIN_S = 0.25
#: After nav last drove or gave feedback, its robot's poses are taken at every drain for this long (s).
ACTIVE_FOR_S = 1.0
#: Queries of one kind that wait for the loop; a flood beyond it drops the oldest (its client's get times out).
QUERIES_CAPACITY = 16
#: The liveliness tokens whose presence the core follows: the roles it needs.
FOLLOWED_ROLES = ("gateway", "odometry")
#: How long a get the edge makes for the core (a gateway's health and parameters when it appears) waits for answers (s).
ASK_TIMEOUT_S = 2.0
#: A goal or a move first asks the gateway for its health (it is published once a second: a link that came up since
#: would still read down), and waits at most this long (s) for it; the gateway's answer comes in about a millisecond.
REFRESH_TIMEOUT_S = 0.25

log = logging.getLogger("blackmetal.nav")


class NavZenoh(ZenohEdge):
    def __init__(
        self, session: "zenoh.Session", keys: Keys, *, burst: PutBurst | None = None, clock: Callable[[], float] = time.monotonic
    ) -> None:
        """One robot; a fleet (``burst``): feedback batched with the other robots' telemetry, commands never."""
        super().__init__(session)
        self.clock = clock
        self._active_until = -math.inf  # a fleet robot's poses are taken at every drain until then (see IDLE_DRAIN_S)
        self._next_idle_take = -math.inf
        self.keys = keys
        command = keys.cmd_vel_of(Sources.NAV)
        self.routes(keys, (command,), fast=command)  # express, never held in a burst
        self.routes(keys, (keys.nav_feedback,), fast=keys.nav_feedback, burst=burst)
        self.routes(keys, (keys.nav_map_pose, keys.nav_params, keys.errors))
        self._ring: zenoh.Subscriber[zenoh.handlers.Handler[zenoh.Sample]] | None = None
        self._host: NavHost | None = None
        #: The last Twist put was not zero: closing, the edge sends a zero so that nothing drives on nav's last word.
        self.moving = False

    def attach(self, host: NavHost, loop: asyncio.AbstractEventLoop, *, ring: bool = False) -> Intake:
        """Declare the inputs that feed ``host``; ``ring`` (a fleet): poses wait for :meth:`drain`, no callback each."""
        intake, keys = self.intake(loop, on_error=host.on_error()), self.keys
        # what stops a goal (e-stop, link, driver, a service gone) is handled before the poses that wait
        health = intake.channel("health", host.on_health, latest=True, priority=1)
        limits = intake.channel("gateway params", host.on_gateway_params, latest=True, priority=1)
        self.subscriber(keys.health, health)
        self.subscriber(keys.driver, intake.channel("driver", host.on_driver, capacity=16, priority=1))
        self.subscriber(keys.params, limits)

        def on_alive(role: str, alive: bool) -> None:
            host.on_alive(role, alive)
            if alive and role == "gateway":  # its health comes each second, its parameters only when they change: ask
                self.ask(keys.health, health)
                self.ask(keys.params, limits)

        for role in FOLLOWED_ROLES:
            self._alive(keys.alive(role), intake.channel(f"alive/{role}", partial(on_alive, role), capacity=16, priority=1))
        if ring:
            import zenoh

            self._ring = self.session.declare_subscriber(keys.pose, zenoh.handlers.RingChannel(RING))
            self._entities.append(self._ring)
            self._host = host
        else:
            self.subscriber(keys.pose, intake.channel("pose", host.on_pose, latest=True))
        queries: dict[str, Callable[[bytes | None], msgspec.Struct]] = {
            keys.nav_goal: self._fresh(host.on_goal),
            keys.nav_move: self._fresh(host.on_move),
            keys.nav_cancel: host.on_cancel,
            keys.nav_result: host.on_result,
            keys.nav_map_pose: host.map_pose,
            keys.nav_set_pose: host.on_set_pose,
            keys.nav_params: host.params,
            keys.nav_params_set: host.on_params_set,
        }
        later = intake.channel("after health", _call, capacity=2 * QUERIES_CAPACITY)
        for key, handler in queries.items():
            answer = self._answerer(key, handler)
            if key in (keys.nav_goal, keys.nav_move):
                answer = self._after_health(answer, health, later)
            self.queryable(key, intake.channel(f"{key.rpartition('/nav/')[2]}?", answer, capacity=QUERIES_CAPACITY))
        recent = host.core.reporter.recent
        self.queryable(keys.errors, intake.channel("errors?", lambda q: self.answer_recent(q, keys.errors, list(recent)), capacity=16))
        self.token(keys.alive_nav)
        return intake

    def publish(self, message: msgspec.Struct) -> None:
        kind = type(message)
        if kind is Twist:
            self.moving = message != Twist()
        if kind is Twist or kind is NavFeedback:
            self._active_until = self.clock() + ACTIVE_FOR_S
        super().publish(message)

    def drain(self) -> int:
        """On the loop (the fleet's drain): the ring's newest pose to the host, the older ones superseded; how many samples
        the ring held. While nav drives nothing, only every IDLE_DRAIN_S, and the newest two (see IDLE_DRAIN_S)."""
        if self._ring is None:
            return 0
        now = self.clock()
        if now < self._active_until:
            return self._take_newest()
        if now >= self._next_idle_take:
            self._next_idle_take = now + IDLE_DRAIN_S
            return self._take_newest(2)
        return 0

    def _fresh(self, handler: Callable[[bytes | None], msgspec.Struct]) -> Callable[[bytes | None], msgspec.Struct]:
        """``handler`` (a goal's, a move's), the ring's newest pose handed to the core first: it plans from where the robot is."""

        def handle(payload: bytes | None) -> msgspec.Struct:
            if self._ring is not None:
                self._take_newest()
                self._active_until = self.clock() + ACTIVE_FOR_S
            return handler(payload)

        return handle

    def _take_newest(self, count: int = 1) -> int:
        """The ``count`` newest poses of the ring to the host, oldest first; how many samples the ring held."""
        ring, host = self._ring, self._host
        if ring is None or host is None:
            return 0
        taken, newest = 0, deque["zenoh.Sample"](maxlen=count)
        while (sample := ring.try_recv()) is not None:
            taken += 1
            newest.append(sample)
        for sample in newest:
            host.on_pose(payload_bytes(sample))
        return taken

    def close(self) -> None:
        """Undeclare everything; a robot nav was driving gets a zero first (the gateway's timeout would stop it later)."""
        self._ring = None
        if self.moving and Twist in self._routes:
            publisher, _ = self._routes[Twist]
            try:
                publisher.put(encode(Twist()))
            except Exception:  # the session is closing under us: the command timeout stops the robot
                pass
            self.moving = False
        super().close()

    def subscriber(self, key: str, put: Callable[[bytes], None]) -> None:
        """:meth:`ZenohEdge.subscriber` with its callback on Zenoh's receiving thread, not a thread of its own: it only
        copies the payload into the intake (a fleet of 100 had 1 600 callback threads)."""
        import zenoh

        handler: zenoh.handlers.Callback[zenoh.Sample] = zenoh.handlers.Callback(lambda sample: put(payload_bytes(sample)), indirect=False)
        self._entities.append(self.session.declare_subscriber(key, handler))

    def queryable(self, key: str, put: Callable[["zenoh.Query"], None]) -> None:
        """:meth:`ZenohEdge.queryable`, its callback on Zenoh's thread: it only hands the query to the intake."""
        import zenoh

        self._entities.append(self.session.declare_queryable(key, zenoh.handlers.Callback(put, indirect=False)))

    def ask(self, key: str, put: Callable[[bytes], None]) -> None:
        """A get on ``key`` that does not wait: each answer's payload goes to ``put`` (an intake channel) from Zenoh's thread."""
        import zenoh

        def on_reply(reply: "zenoh.Reply") -> None:
            if reply.ok is not None:
                put(payload_bytes(reply.ok))

        try:
            self.session.get(key, zenoh.handlers.Callback(on_reply, indirect=False), timeout=ASK_TIMEOUT_S)
        except Exception as exc:  # the session is closing: nothing to ask any more
            log.debug("get on %s refused: %s", key, exc)

    def _alive(self, key: str, put: Callable[[bool], None]) -> None:
        """A liveliness subscriber with history: ``put(True)`` for a token present now or later, ``put(False)`` when it goes."""
        import zenoh

        def on_sample(sample: "zenoh.Sample") -> None:
            put(sample.kind == zenoh.SampleKind.PUT)

        handler: zenoh.handlers.Callback[zenoh.Sample] = zenoh.handlers.Callback(on_sample, indirect=False)
        self._entities.append(self.session.liveliness().declare_subscriber(key, handler, history=True))

    def _after_health(
        self,
        answer: Callable[["zenoh.Query"], None],
        health: Callable[[bytes], None],
        later: Callable[[tuple[Callable[["zenoh.Query"], None], "zenoh.Query"]], None],
    ) -> Callable[["zenoh.Query"], None]:
        """``answer`` once the gateway's health is asked for and handed to the core (its replies go into ``health``, a
        channel the intake serves first; the get's end puts the query into ``later``), or REFRESH_TIMEOUT_S passed."""
        import zenoh

        def first(query: "zenoh.Query") -> None:
            pending = [query]  # answered once: by the get's end, or here if the get is refused

            def on_reply(reply: "zenoh.Reply") -> None:
                if reply.ok is not None:
                    health(payload_bytes(reply.ok))

            def done() -> None:
                if pending:
                    later((answer, pending.pop()))

            try:
                self.session.get(self.keys.health, zenoh.handlers.Callback(on_reply, drop=done, indirect=False), timeout=REFRESH_TIMEOUT_S)
            except Exception as exc:  # the session is closing: answer with what the core knows
                log.debug("get on %s refused: %s", self.keys.health, exc)
                done()

        return first

    def _answerer(self, key: str, handler: Callable[[bytes | None], msgspec.Struct]) -> Callable[["zenoh.Query"], None]:
        """On the loop: the query's payload to ``handler``, its answer replied as JSON (a PayloadError: an error reply)."""

        def answer(query: "zenoh.Query") -> None:
            import zenoh

            with query:
                payload = None if query.payload is None else bytes(query.payload.to_bytes())
                try:
                    reply = handler(payload)
                except PayloadError as exc:
                    query.reply_err(str(exc).encode())
                    return
                query.reply(key, encode(reply), encoding=zenoh.Encoding.APPLICATION_JSON)

        return answer


def _call(item: tuple[Callable[["zenoh.Query"], None], "zenoh.Query"]) -> None:
    answer, query = item
    answer(query)
