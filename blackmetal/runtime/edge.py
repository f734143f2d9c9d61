"""The one way a service meets Zenoh: declare at the edge, hand every sample to the service's intake.

:class:`ZenohEdge` undeclares what it declared newest first; inputs a client may flood go through
:meth:`ZenohEdge.guarded` (:class:`~blackmetal.runtime.flood.GuardedInput`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING, Any

import msgspec

from blackmetal.schemas import ConfigError, Delivery, ErrorReport, Keys, any_alive, delivery_of, encode, payload_bytes

from .burst import PutBurst
from .flood import GuardedInput
from .intake import Intake
from .zenoh_entities import undeclare

if TYPE_CHECKING:
    import asyncio

    import zenoh


def refuse_taken(
    session: "zenoh.Session",
    role: str,
    prefixes: Sequence[str],
    *,
    what: str | None = None,
    describe: Callable[[str], str] | None = None,
) -> None:
    """ConfigError naming the first prefix on which another ``role`` is alive (one liveliness query; call before
    declaring our own tokens). ``what`` names the service (default ``role``), ``describe(prefix)`` a fleet's robot."""
    alive = {
        Keys.prefix_of_token(str(reply.ok.key_expr), role)
        for reply in session.liveliness().get(any_alive(role), timeout=0.5)
        if reply.ok is not None
    }
    for prefix in prefixes:
        if prefix in alive:
            who = f"{describe(prefix)}: " if describe is not None else ""
            fix = "give this robot another prefix" if describe is not None else "give this one another --prefix (e.g. --prefix fleet/b)"
            raise ConfigError(
                f"{who}another {what or role} is already alive on prefix {prefix!r} ({Keys(prefix).alive(role)}); one robot per prefix: "
                f"stop the other one, or {fix}"
            )


class ZenohEdge:
    """Declares a service's Zenoh entities on an open session and undeclares them, newest first."""

    def __init__(self, session: "zenoh.Session") -> None:
        self.session = session
        #: Each message type the service publishes -> its publisher, and the burst that holds it (None: put at once).
        self._routes: dict[type, tuple[Any, PutBurst | None]] = {}
        self._entities: list[Any] = []
        self._guarded: list[GuardedInput] = []
        self._intakes: list[Intake] = []

    def intake(self, loop: "asyncio.AbstractEventLoop", **options: Any) -> Intake:
        """The service's intake (see :class:`Intake` for ``options``); closed by :meth:`close` before anything is undeclared."""
        intake = Intake(loop, **options)
        self._intakes.append(intake)
        return intake

    def publisher(self, keys: Keys, key: str, *, express: bool = False) -> "zenoh.Publisher":
        """A publisher on one of blackmetal's keys, its congestion control as the key space says (:func:`delivery_of`):
        telemetry dropped for a congested link alone, commands never dropped."""
        import zenoh

        telemetry = delivery_of(key, keys.prefix) is Delivery.TELEMETRY
        publisher = self.session.declare_publisher(
            key,
            encoding=zenoh.Encoding.APPLICATION_JSON,
            express=express,
            congestion_control=zenoh.CongestionControl.DROP if telemetry else zenoh.CongestionControl.BLOCK,
        )
        self._entities.append(publisher)
        return publisher

    def routes(self, keys: Keys, published: Iterable[str], *, fast: str | None = None, burst: PutBurst | None = None) -> None:
        """A publisher for each key of ``published``; :meth:`publish` routes a message to it by its type.

        ``fast`` (high-rate telemetry): express for one robot; in a fleet batched through ``burst``.
        """
        for key in published:
            message = keys.message_for(key)
            assert message is not None, key
            self._routes[message] = (self.publisher(keys, key, express=key == fast and burst is None), burst if key == fast else None)

    def publish(self, message: msgspec.Struct) -> None:
        """``message`` put on its key (see :meth:`routes`)."""
        publisher, burst = self._routes[type(message)]
        if burst is None:
            publisher.put(encode(message))
        else:
            burst.put(publisher, encode(message))

    def watch_matching(self, publisher: Any, on_change: Callable[[bool], None]) -> None:
        """Whether anyone subscribes to ``publisher``'s key: ``on_change`` now, and on a Zenoh thread at each change.

        ``on_change`` runs in a Zenoh callback: it may only hand the answer over (a channel's put, a flag).
        """

        def matching(status: Any) -> bool:
            return bool(getattr(status, "matching", status))  # the stubs say bool; zenoh 1.x gives a MatchingStatus

        self._entities.append(publisher.declare_matching_listener(lambda status: on_change(matching(status))))
        on_change(matching(publisher.matching_status))

    def subscriber(self, key: str, put: Callable[[bytes], None]) -> None:
        """Payload bytes of every sample on ``key`` go to ``put`` (an Intake channel)."""
        self._entities.append(self.session.declare_subscriber(key, lambda sample: put(payload_bytes(sample))))

    def guarded(
        self,
        key: str,
        put: Callable[[Any], None],
        intake: Intake,
        on_flood: Callable[[str, str], None] | None = None,
        **options: Any,
    ) -> "GuardedInput":
        """``(last key chunk, payload)`` of samples on ``key`` go to ``put``; for inputs a client may flood (see
        :class:`GuardedInput` for ``options``)."""
        guarded = GuardedInput(self.session, key, put, intake, on_flood, **options)
        guarded.start()
        self._guarded.append(guarded)
        return guarded

    def queryable(self, key: str, put: Callable[["zenoh.Query"], None]) -> None:
        """Every query on ``key`` goes to ``put``; the handler answers it on the loop (``with query: ...``)."""
        self._entities.append(self.session.declare_queryable(key, put))

    @staticmethod
    def answer_recent(query: "zenoh.Query", key: str, reports: Iterable[ErrorReport]) -> None:
        """A get on an errors key: one reply per recent report of this service, oldest first (a view started later sees them)."""
        import zenoh

        with query:
            for report in reports:
                query.reply(key, encode(report), encoding=zenoh.Encoding.APPLICATION_JSON)

    def token(self, key: str) -> None:
        """A liveliness token, present while this edge is open."""
        self._entities.append(self.session.liveliness().declare_token(key))

    def close(self) -> None:
        for intake in self._intakes:  # first: a drain already scheduled must not publish through what follows
            intake.close()
        for guarded in reversed(self._guarded):
            guarded.close()
        self._guarded.clear()
        for entity in reversed(self._entities):
            undeclare(entity)
        self._entities.clear()
