"""Zenoh edge of the navigation service: its input table and its outputs, declarations only.

Inputs reach the host on the service's loop through one intake; liveliness subscribers ask for history, so a gateway
or an odometry alive before nav started is seen at once (any start order), and a gateway that appears is asked for its
health and its parameters (published each second and only on a change). A fleet robot follows its poses only while its
navigation drives (a ring the loop drains): a goal asks for the pose and the health first, and an idle fleet costs the
router and nav no pose at all. Outputs are routed by type (:meth:`ZenohEdge.routes`): ``Twist`` to ``cmd_vel/nav`` (a command:
never dropped, express), ``NavFeedback``, ``MapPose``, ``GatewayParams`` (``nav/params``) and ``ErrorReport``.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING

import msgspec

from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.edge import ZenohEdge
from blackmetal.runtime.intake import Intake
from blackmetal.runtime.zenoh_entities import undeclare
from blackmetal.schemas import GatewayHealth, Keys, NavFeedback, PayloadError, Sources, Twist, WheelMove, decode, encode, payload_bytes

from .host import NavHost

if TYPE_CHECKING:
    import zenoh

#: A fleet robot's poses wait in a Zenoh ring of this many for :meth:`NavZenoh.drain` (which takes the newest).
RING = 4
#: A fleet robot follows its poses (a subscriber) from a goal, a move or a set-pose until this long (s) after its
#: navigation last drove or gave feedback; then it undeclares it, and asks for the pose with the next one.
ACTIVE_FOR_S = 1.0
#: Queries of one kind that wait for the loop; a flood beyond it drops the oldest (its client's get times out). The
#: core answers a goal in microseconds, so they wait only for a burst: 300 goals sent at once left 13 unanswered with
#: 16 places, none with this many (each a refused or a preempting goal, with its sentence).
QUERIES_CAPACITY = 1024
#: The liveliness tokens whose presence the core follows: the roles it needs.
FOLLOWED_ROLES = ("gateway", "odometry")
#: How long a get the edge makes for the core (a gateway's health and parameters when it appears) waits for answers (s).
ASK_TIMEOUT_S = 2.0
#: A goal or a move first asks the gateway for its health (it is published once a second: a link that came up since
#: would still read down) and, in a fleet, the odometry for the pose, and waits at most this long (s) for them; their
#: answers come in about a millisecond.
REFRESH_TIMEOUT_S = 0.25

log = logging.getLogger("blackmetal.nav")


class NavZenoh(ZenohEdge):
    def __init__(
        self,
        session: "zenoh.Session",
        keys: Keys,
        *,
        burst: PutBurst | None = None,
        clock: Callable[[], float] = time.monotonic,
        command_hz: float = 0.0,
    ) -> None:
        """One robot; a fleet (``burst``): feedback batched with the other robots' telemetry, commands never.

        ``command_hz`` > 0: at most that many commands a second, the newest held until its turn (a stop never waits)."""
        super().__init__(session)
        self.clock = clock
        self._command_period = 1.0 / command_hz if command_hz > 0 else 0.0
        self._last_command_at = -math.inf
        self._held: Twist | None = None  # the newest command waiting for its turn (command_hz)
        self._held_timer: asyncio.TimerHandle | None = None
        self._active_until = -math.inf  # a fleet robot follows its poses until then (see ACTIVE_FOR_S)
        self._following = False  # a fleet robot (ring mode): poses wait for drain() in self._ring while it drives
        self._ready = False  # the last health said the robot can drive (see _noting_ready)
        self.keys = keys
        command = keys.cmd_vel_of(Sources.NAV)
        self.routes(keys, (command,), fast=command)  # express, never held in a burst
        self.routes(keys, (keys.nav_feedback,), fast=keys.nav_feedback, burst=burst)
        self.routes(keys, (keys.nav_map_pose, keys.nav_params, keys.errors))
        self._ring: zenoh.Subscriber[zenoh.handlers.Handler[zenoh.Sample]] | None = None
        self._host: NavHost | None = None
        self._move_replies: Callable[[bytes], None] | None = None  # the gateway's answers to a robot move (intake channel)
        #: The last Twist put was not zero: closing, the edge sends a zero so that nothing drives on nav's last word.
        self.moving = False

    def attach(self, host: NavHost, loop: asyncio.AbstractEventLoop, *, ring: bool = False) -> Intake:
        """Declare the inputs that feed ``host``; ``ring`` (a fleet): poses wait for :meth:`drain`, no callback each."""
        intake, keys = self.intake(loop, on_error=host.on_error()), self.keys
        # what stops a goal (e-stop, link, driver, a service gone) is handled before the poses that wait
        health = intake.channel("health", self._noting_ready(host.on_health), latest=True, priority=1)
        limits = intake.channel("gateway params", host.on_gateway_params, latest=True, priority=1)
        self.subscriber(keys.health, health)
        self.subscriber(keys.driver, intake.channel("driver", host.on_driver, capacity=16, priority=1))
        self.subscriber(keys.params, limits)
        self.subscriber(keys.wheels_position, intake.channel("wheels position", host.on_wheel_position, latest=True, priority=1))
        self._move_replies = intake.channel("wheels move!", host.on_wheel_move_reply, capacity=4, priority=1)

        def on_alive(role: str, alive: bool) -> None:
            host.on_alive(role, alive)
            if alive and role == "gateway":  # its health comes each second, its parameters only when they change: ask
                self.ask(keys.health, health)
                self.ask(keys.params, limits)

        for role in FOLLOWED_ROLES:
            self._alive(keys.alive(role), intake.channel(f"alive/{role}", partial(on_alive, role), capacity=16, priority=1))
        pose = intake.channel("pose", host.on_pose, latest=True, priority=1 if ring else 0)
        if ring:  # a fleet: poses only while driving; a goal asks for the pose first (before the query, priority 1)
            self._host = host
        else:
            self.subscriber(keys.pose, pose)

        def for_a_goal() -> list[tuple[str, Callable[[bytes], None]]]:
            """What a goal or a move asks for first: the health unless the last said the robot can drive (an e-stop and a
            link lost are published at once, a link that came up only within a second), a fleet robot's pose unless
            it follows its poses."""
            return [(keys.health, health)] * (not self._ready) + [(keys.pose, pose)] * (ring and not self._following)

        def for_a_set_pose() -> list[tuple[str, Callable[[bytes], None]]]:
            return [(keys.pose, pose)] * (ring and not self._following)

        queries: dict[str, Callable[[bytes | None], msgspec.Struct]] = {
            keys.nav_goal: self._following_poses(host.on_goal),
            keys.nav_move: self._following_poses(host.on_move),
            keys.nav_cancel: host.on_cancel,
            keys.nav_result: host.on_result,
            keys.nav_map_pose: host.map_pose,
            keys.nav_set_pose: self._following_poses(host.on_set_pose),
            keys.nav_params: host.params,
            keys.nav_params_set: host.on_params_set,
        }
        first = {keys.nav_goal: for_a_goal, keys.nav_move: for_a_goal, keys.nav_set_pose: for_a_set_pose}
        later = intake.channel("after asking", _call, capacity=2 * QUERIES_CAPACITY)
        for key, handler in queries.items():
            answer = self._answerer(key, handler)
            if key in first:
                answer = self._after_asking(answer, first[key], later)
            self.queryable(key, intake.channel(f"{key.rpartition('/nav/')[2]}?", answer, capacity=QUERIES_CAPACITY))
        recent = host.core.reporter.recent
        self.queryable(keys.errors, intake.channel("errors?", lambda q: self.answer_recent(q, keys.errors, list(recent)), capacity=16))
        self.token(keys.alive_nav)
        return intake

    def publish(self, message: msgspec.Struct) -> None:
        kind = type(message)
        if kind is WheelMove:  # a robot move is a get on the gateway's wheels/move; its answer goes to the core
            if self._move_replies is not None:
                self.ask(self.keys.wheels_move, self._move_replies, encode(message))
            return
        if kind is Twist or kind is NavFeedback:
            self._active_until = self.clock() + ACTIVE_FOR_S
        if kind is Twist:
            self.moving = message != Twist()
            if self._command_period:
                self._pace(message)  # type: ignore[arg-type]
                return
        super().publish(message)

    def _pace(self, twist: Twist) -> None:
        """``command_hz``: a command goes now if its turn came, else it waits (the newest replacing the one waiting) until
        its turn; a stop goes at once and drops what waits."""
        now = self.clock()
        due = self._last_command_at + self._command_period
        if self.moving and now < due:
            self._held = twist
            if self._held_timer is None:
                self._held_timer = asyncio.get_running_loop().call_later(due - now, self._send_held)
            return
        self._drop_held()
        self._last_command_at = now
        ZenohEdge.publish(self, twist)

    def _send_held(self) -> None:
        self._held_timer = None
        held, self._held = self._held, None
        if held is not None:
            self._last_command_at = self.clock()
            ZenohEdge.publish(self, held)

    def _drop_held(self) -> None:
        self._held = None
        if self._held_timer is not None:
            self._held_timer.cancel()
            self._held_timer = None

    def drain(self) -> int:
        """On the loop (the fleet's drain): the ring's newest pose to the host, the older ones superseded; how many samples
        the ring held. Past ACTIVE_FOR_S without driving, the robot stops following its poses."""
        ring, host = self._ring, self._host
        if ring is None or host is None:
            return 0
        if self.clock() >= self._active_until:
            self.follow(False)
            return 0
        taken, newest = 0, None
        while (sample := ring.try_recv()) is not None:
            taken += 1
            newest = sample
        if newest is not None:
            host.on_pose(payload_bytes(newest))
        return taken

    def follow(self, on: bool) -> None:
        """A fleet robot: declare (or undeclare) the ring of its poses; on the loop."""
        if on == self._following:
            return
        self._following = on
        if on:
            import zenoh

            self._ring = self.session.declare_subscriber(self.keys.pose, zenoh.handlers.RingChannel(RING))
        elif self._ring is not None:
            ring, self._ring = self._ring, None
            undeclare(ring)

    def _following_poses(self, handler: Callable[[bytes | None], msgspec.Struct]) -> Callable[[bytes | None], msgspec.Struct]:
        """``handler`` (a goal's, a move's, a set-pose's); a fleet robot follows its poses from then on."""

        def handle(payload: bytes | None) -> msgspec.Struct:
            if self._host is not None:
                self._active_until = self.clock() + ACTIVE_FOR_S
                self.follow(True)
            return handler(payload)

        return handle

    def close(self) -> None:
        """Undeclare everything; a robot nav was driving gets a zero first (the gateway's timeout would stop it later)."""
        self._drop_held()
        self.follow(False)
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

    def ask(self, key: str, put: Callable[[bytes], None], payload: bytes | None = None) -> None:
        """A get on ``key`` (with ``payload``) that does not wait: each answer's payload goes to ``put`` (an intake
        channel) from Zenoh's thread."""
        import zenoh

        def on_reply(reply: "zenoh.Reply") -> None:
            if reply.ok is not None:
                put(payload_bytes(reply.ok))

        try:
            self.session.get(key, zenoh.handlers.Callback(on_reply, indirect=False), payload=payload, timeout=ASK_TIMEOUT_S)
        except Exception as exc:  # the session is closing: nothing to ask any more
            log.debug("get on %s refused: %s", key, exc)

    def _alive(self, key: str, put: Callable[[bool], None]) -> None:
        """A liveliness subscriber with history: ``put(True)`` for a token present now or later, ``put(False)`` when it goes."""
        import zenoh

        def on_sample(sample: "zenoh.Sample") -> None:
            put(sample.kind == zenoh.SampleKind.PUT)

        handler: zenoh.handlers.Callback[zenoh.Sample] = zenoh.handlers.Callback(on_sample, indirect=False)
        self._entities.append(self.session.liveliness().declare_subscriber(key, handler, history=True))

    def _noting_ready(self, on_health: Callable[[bytes], None]) -> Callable[[bytes], None]:
        """``on_health``, the edge noting whether the health said the robot can drive (connected, no e-stop): only then
        does a goal go to the core without asking for the health first. The core decides alone what the health means."""

        def handle(payload: bytes) -> None:
            try:
                health = decode(GatewayHealth, payload)
                self._ready = health.control.state == "connected" and not health.estop
            except PayloadError:
                self._ready = False
            on_health(payload)

        return handle

    def _after_asking(
        self,
        answer: Callable[["zenoh.Query"], None],
        asks: Callable[[], list[tuple[str, Callable[[bytes], None]]]],
        later: Callable[[tuple[Callable[["zenoh.Query"], None], "zenoh.Query"]], None],
    ) -> Callable[["zenoh.Query"], None]:
        """``answer`` once each key ``asks()`` names now (the gateway's health; a fleet robot's pose) was asked for and
        its answers handed to the core (into their channels, which the intake serves first), at most REFRESH_TIMEOUT_S
        later: the last get's end puts the query into ``later``. Nothing to ask: answered at once."""
        import zenoh

        def first(query: "zenoh.Query") -> None:
            asked = asks()
            if not asked:
                answer(query)
                return
            pending = [query]  # answered once: after the last get's end
            left = [len(asked)]

            def done() -> None:
                left[0] -= 1
                if left[0] <= 0 and pending:
                    later((answer, pending.pop()))

            for key, put in asked:

                def on_reply(reply: "zenoh.Reply", put: Callable[[bytes], None] = put) -> None:
                    if reply.ok is not None:
                        put(payload_bytes(reply.ok))

                try:
                    self.session.get(key, zenoh.handlers.Callback(on_reply, drop=done, indirect=False), timeout=REFRESH_TIMEOUT_S)
                except Exception as exc:  # the session is closing: answer with what the core knows
                    log.debug("get on %s refused: %s", key, exc)
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
