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

        self.bugs: list[BaseException] = []

    def on_health(self, robot_id: str, payload: bytes) -> None:
        self.health.append(payload)

    def on_bug(self, robot_id: str, exc: BaseException) -> None:
        self.bugs.append(exc)

    def on_reset_reply(self, robot_id: str, reply: object) -> None: ...
    def on_params(self, robot_id: str, payload: bytes) -> None: ...
    def on_params_reply(self, robot_id: str, reply: object) -> None: ...


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
    assert NO_EDGE.declared == frozenset() and NO_EDGE.drain() == 0 and NO_EDGE.latest_pose() is None
