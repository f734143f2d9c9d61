"""How the view's parts meet: the wiring takes each edge's answers and reaches every robot's edge (fakes, no I/O)."""

from __future__ import annotations

from typing import Any

from blackmetal.foxglove.controls import Controls
from blackmetal.foxglove.live import LiveView
from blackmetal.foxglove.ports import Wiring
from blackmetal.foxglove.watch import Watch
from blackmetal.foxglove.zenoh_edge import NO_EDGE
from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import ErrorReport, Keys
from unit.foxglove.test_controls import health
from unit.foxglove.test_fleet_view import Logged


class FakeHost:
    """The host's side the wiring uses: its clock, the timer's poke, its parameters (itself), the clients."""

    def __init__(self) -> None:
        self.pokes = 0
        self.replies: list[tuple[str, tuple[int, bytes | None, bytes | None]]] = []
        self.tables: list[tuple[str, bytes]] = []
        self.answers: dict[int, tuple[bytes | None, str | None]] = {}

    def clock(self) -> float:
        return 5.0

    def poke(self) -> None:
        self.pokes += 1

    @property
    def params(self) -> FakeHost:
        return self

    def on_set_reply(self, robot_id: str, call: int, ok: bytes | None, err: bytes | None, now: float) -> None:
        self.replies.append((robot_id, (call, ok, err)))

    def on_table(self, robot_id: str, payload: bytes, now: float) -> None:
        self.tables.append((robot_id, payload))

    def answer(self, call: int, response: bytes | None, failure: str | None) -> None:
        self.answers[call] = (response, failure)

    def status(self, *args: Any) -> None: ...


class FakeEdge:
    """A robot's edge that keeps what it was asked."""

    declared: frozenset[str] = frozenset()

    def __init__(self) -> None:
        self.wanted: set[str] | None = None
        self.asks = 0
        self.sets: list[tuple[int, bytes]] = []
        self.errors: list[ErrorReport] = []
        self.peeking: bool | None = None

    def want(self, keys: set[str]) -> None:
        self.wanted = keys

    def ask_params(self) -> None:
        self.asks += 1

    def set_params(self, call: int, payload: bytes) -> None:
        self.sets.append((call, payload))

    def error(self, message: ErrorReport) -> None:
        self.errors.append(message)

    def ask_health(self) -> None: ...

    def peek(self, on: bool) -> None:
        self.peeking = on

    def latest_pose(self) -> bytes:
        return b"pose"


def wiring(host: FakeHost, *robot_ids: str, reporter: ErrorReporter | None = None) -> Wiring:
    views, controls = {}, {}
    logs: dict[str, list[Any]] = {}
    for robot_id in robot_ids:
        keys = Keys(f"fleet/{robot_id}" if robot_id else "robot")
        views[robot_id] = LiveView(keys, channel=lambda topic, kind, schema: Logged(topic, kind, schema, logs))
        controls[robot_id] = Controls(keys, host, wallclock=lambda: 1000.0)  # type: ignore[arg-type]
    return Wiring(host, views, controls, Watch(views[robot_ids[0]].feeds()), fleet_reporter=reporter)  # type: ignore[arg-type]


def test_a_robot_is_reached_only_through_the_edge_plugged_in() -> None:
    host = FakeHost()
    one = wiring(host, "")
    assert one.edges[""] is NO_EDGE and one.controls[""].robot is NO_EDGE
    edge = FakeEdge()
    one.plug("", edge)  # type: ignore[arg-type]
    assert one.controls[""].robot is edge
    one.on_token("", True)
    assert edge.asks == 1, "a gateway that came back is asked its parameters"
    one.on_bug("", ValueError("boom"))
    (report,) = edge.errors
    assert report.key == "foxglove:view" and "showing robot failed: ValueError('boom')" in report.reason
    one.on_params("", b"table")
    assert host.tables == [("", b"table")]
    one.on_health("", health(True))
    assert one.controls[""].estop_seen is True and host.pokes >= 2
    one.plug("", NO_EDGE)
    assert one.controls[""].robot is NO_EDGE


def test_the_wiring_asks_the_right_robot_and_answers_a_set_no_session_can_carry() -> None:
    host = FakeHost()
    fleet_reports: list[ErrorReport] = []
    both = wiring(host, "r1", "r2", reporter=ErrorReporter("foxglove", fleet_reports.append, lambda: 1000.0))
    edge = FakeEdge()
    both.plug("r1", edge)  # type: ignore[arg-type]
    both.ask_params("r1")
    both.set_params("r1", 3, b"{}")
    both.set_params("r2", 4, b"{}")
    assert edge.asks == 1 and edge.sets == [(3, b"{}")]
    assert host.replies == [("r2", (4, None, None))], "no edge: the set ends unanswered at once"
    assert both.latest_pose("r1") == b"pose" and both.latest_pose("r2") is None and both.latest_pose("r9") is None
    both.report("r1", "parameters", "bad value", "", now=5.0)
    both.report(None, "parameters", "names no robot", "", now=5.0)
    assert [r.reason for r in edge.errors] == ["bad value"] and [r.reason for r in fleet_reports] == ["names no robot"]


def test_the_watch_decides_which_keys_each_edge_follows() -> None:
    host = FakeHost()
    one = wiring(host, "")
    edge = FakeEdge()
    one.plug("", edge)  # type: ignore[arg-type]
    one.watch_changed()
    assert edge.wanted == set(), "nobody watches: nothing is followed"
    one.watch.subscribe(1, "/odometry")
    one.watch_changed()
    assert edge.wanted == {"robot/pose"}
