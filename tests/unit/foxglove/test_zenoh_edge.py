"""The view's Zenoh edge: a key followed only while wanted, its samples waiting in a ring for the drain; the null edge.

One in-process peer session, no endpoints: nothing leaves the process.
"""

from __future__ import annotations

import zenoh
from helpers import wait_for

from blackmetal.foxglove.zenoh_edge import NO_EDGE, RING, FoxgloveZenoh
from blackmetal.schemas import ErrorReport, Keys
from unit.runtime.test_edge import loop  # noqa: F401  (the fixture: a running loop on its own thread)

KEYS = Keys("edge")


class Answers:
    def __init__(self) -> None:
        self.health: list[bytes] = []
        self.nav: list[tuple[int, bytes | None, bytes | None]] = []

        self.bugs: list[BaseException] = []

    def on_health(self, robot_id: str, payload: bytes) -> None:
        self.health.append(payload)

    def on_bug(self, robot_id: str, exc: BaseException) -> None:
        self.bugs.append(exc)

    def on_reset_reply(self, robot_id: str, reply: object) -> None: ...
    def on_params(self, robot_id: str, payload: bytes) -> None: ...
    def on_params_reply(self, robot_id: str, reply: object) -> None: ...

    def on_nav_reply(self, robot_id: str, reply: tuple[int, bytes | None, bytes | None]) -> None:
        self.nav.append(reply)


def test_a_key_is_followed_only_while_wanted_and_a_slow_drain_keeps_the_newest(session: zenoh.Session, loop: object) -> None:  # noqa: F811
    seen: list[bytes] = []
    answers = Answers()
    bugs = answers.bugs

    def on_pose(payload: bytes) -> None:
        if payload == b"bad":
            raise ValueError(payload)
        seen.append(payload)

    edge = FoxgloveZenoh(session, KEYS)
    try:
        edge.attach("", {KEYS.pose: on_pose, KEYS.health: seen.append}, answers, loop)  # type: ignore[arg-type]
        session.put(KEYS.pose, b"unwatched")
        edge.want({KEYS.pose, KEYS.health, "edge/not/a/view/key"})
        assert edge.declared == {KEYS.pose, KEYS.health}, "only the view's keys"
        for i in range(RING + 5):
            session.put(KEYS.pose, str(i).encode())
        wait_for(lambda: edge.drain() or seen, what="the poses")
        assert seen == [str(i).encode() for i in range(5, RING + 5)], "the ring keeps the newest RING"
        session.put(KEYS.pose, b"bad")
        session.put(KEYS.health, b"h")
        wait_for(lambda: edge.drain() or len(seen) > RING, what="the health")
        assert seen[-1] == b"h" and answers.health == [b"h"], "health to the view and to the port"
        assert [str(bug) for bug in bugs] == ["b'bad'"], "a handler that raises is reported, the next sample goes on"
        edge.want(set())
        assert edge.declared == set()
        session.put(KEYS.pose, b"gone")
        assert edge.drain() == 0
    finally:
        edge.close()


def test_the_map_frame_is_asked_for_when_first_wanted_and_nav_queries_answer_in_order(session: zenoh.Session, loop: object) -> None:  # noqa: F811
    placed: list[bytes] = []
    answers = Answers()
    asked: list[bytes] = []

    def navigation(query: zenoh.Query) -> None:  # a stand-in for the navigation service's queryables
        if str(query.key_expr) == KEYS.nav_map_pose:
            return query.reply(KEYS.nav_map_pose, b"map pose")
        asked.append(query.payload.to_bytes() if query.payload is not None else b"")
        query.reply(str(query.key_expr), b"accepted")

    queryable = session.declare_queryable("edge/nav/**", navigation)
    edge = FoxgloveZenoh(session, KEYS)
    try:
        edge.attach("", {KEYS.nav_map_pose: placed.append, KEYS.health: lambda payload: None}, answers, loop)  # type: ignore[arg-type]
        edge.want({KEYS.nav_map_pose})
        wait_for(lambda: placed == [b"map pose"], what="the map pose, asked for")
        edge.want({KEYS.nav_map_pose, KEYS.health})
        session.put(KEYS.nav_map_pose, b"moved")
        wait_for(lambda: edge.drain() or placed[-1] == b"moved", what="the map pose, published")
        assert placed == [b"map pose", b"moved"], "asked once, when it began to be followed"
        edge.ask_nav(KEYS.nav_goal, 7, b'{"x": 1.0, "y": 2.0}')
        wait_for(lambda: len(answers.nav) == 2, what="the reply and its end")
        assert answers.nav == [(7, b"accepted", None), (7, None, None)] and asked == [b'{"x": 1.0, "y": 2.0}']
    finally:
        edge.close()
        queryable.undeclare()


def test_the_summary_peeks_at_the_latest_pose_and_keeps_it(session: zenoh.Session) -> None:
    edge = FoxgloveZenoh(session, KEYS)
    try:
        assert edge.latest_pose() is None
        edge.peek(True)
        session.put(KEYS.pose, b"one")
        session.put(KEYS.pose, b"two")
        assert wait_for(lambda: edge.latest_pose() == b"two", what="the latest pose")
        assert edge.latest_pose() == b"two", "kept when none came since"
        edge.peek(False)
        assert edge.latest_pose() is None
    finally:
        edge.close()


def test_the_null_edge_sends_nowhere_and_follows_nothing() -> None:
    NO_EDGE.command(KEYS.estop, b"{}")
    NO_EDGE.error(ErrorReport(stamp=1.0, source="foxglove", key="k", reason="r"))
    NO_EDGE.want({KEYS.pose})
    NO_EDGE.ask_nav(KEYS.nav_goal, 1, b"{}")
    assert NO_EDGE.declared == frozenset() and NO_EDGE.drain() == 0 and NO_EDGE.latest_pose() is None
