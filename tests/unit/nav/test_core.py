"""NavCore with an injected clock and a simulated robot: goals run and end with their reasons, every bad input gets its
sentence and moves nothing, the robot gets one zero twist when a goal ends early and then nothing."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import msgspec
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from blackmetal.nav.core import NavCore
from blackmetal.nav.params import NavParams
from blackmetal.schemas import (
    DriverChange,
    ErrorReport,
    GatewayHealth,
    GatewayParams,
    GoalState,
    Keys,
    LinkHealth,
    MapPose,
    NavFeedback,
    Param,
    PayloadError,
    Twist,
    encode,
    make_pose,
)

from .kinematics import PERIOD, Robot

KEYS = Keys("robot")
GOAL_A, GOAL_B = "a" * 32, "b" * 32


@dataclass
class Out:
    """Everything the core published, by kind."""

    twists: list[Twist] = field(default_factory=list)
    feedback: list[NavFeedback] = field(default_factory=list)
    map_poses: list[MapPose] = field(default_factory=list)
    params: list[GatewayParams] = field(default_factory=list)
    errors: list[ErrorReport] = field(default_factory=list)

    def __call__(self, message: object) -> None:
        kinds = {
            Twist: self.twists,
            NavFeedback: self.feedback,
            MapPose: self.map_poses,
            GatewayParams: self.params,
            ErrorReport: self.errors,
        }
        kinds[type(message)].append(message)  # type: ignore[index]


def health(estop: bool = False, link: str = "connected", source: str | None = None, stamp: float = 0.0) -> bytes:
    reason = None if link == "connected" else "cannot connect to 192.0.2.1:665: Connection refused"
    return encode(
        GatewayHealth(
            stamp,
            LinkHealth(link, reason=reason),
            LinkHealth("connected"),
            estop=estop,
            active_source=source,
            estop_by="robot/estop" if estop else None,
            estop_since=1.8e9 if estop else None,
        )
    )


class Bench:
    """A NavCore wired to a simulated robot: the gateway runs the latest twist (its command timeout: 0.5 s), the
    odometry reports a pose every period, the core's deadlines are kept."""

    def __init__(self, map_pose: MapPose | None = None, geofence: tuple[float, float, float, float] | None = None, **params: float) -> None:
        self.out = Out()
        self.now = 0.0
        self.core = NavCore(
            NavParams(**params),
            KEYS,
            self.out,
            map_pose=map_pose or MapPose(0.0, 0.0, 0.0, 0.0),
            geofence=geofence,
            wallclock=lambda: 1.8e9 + self.now,
        )
        self.robot = Robot()
        self.moves = True  # the wheels follow the commands (False: blocked)
        self.arbiter = True  # the gateway says the nav drives once it commands (False: someone else keeps driving)
        self._driver: str | None = None
        self.poses = True  # the odometry publishes
        self._command = (0.0, 0.0)
        self._heard = -math.inf
        assert self.core.next_deadline() == -math.inf  # the first tick is due at once
        self.core.tick(self.now)
        self.core.on_alive("gateway", True, self.now)
        self.core.on_alive("odometry", True, self.now)
        self.core.on_health(health(), self.now)
        self.pose()

    def pose(self) -> None:
        x, y, yaw = self.robot.pose()
        self.core.on_pose(encode(make_pose(1.8e9 + self.now, x, y, yaw, self.robot.v, self.robot.w)), self.now)

    def run(self, seconds: float) -> None:
        """``seconds`` of robot time: a pose each period while ``poses``, the core ticked at its deadlines."""
        end = self.now + seconds - 1e-9
        while self.now < end:
            seen = len(self.out.twists)
            if self.poses:
                self.pose()
            if len(self.out.twists) > seen:
                t = self.out.twists[-1]
                self._command, self._heard = (t.linear.x, t.angular.z), self.now
                if self.arbiter and self._driver != "nav":
                    self._driver = "nav"
                    self.core.on_driver(encode(DriverChange(1.8e9 + self.now, "nav", None, "nav drives: nobody drove")), self.now)
            self._tick_until(self.now + PERIOD)
            if self.now - self._heard > 0.5:  # the gateway's command timeout
                self._command = (0.0, 0.0)
            self.robot.run(*(self._command if self.moves else (0.0, 0.0)))
            if not self.moves:
                self.robot.v = self.robot.w = 0.0
            self.now += PERIOD

    def _tick_until(self, until: float) -> None:
        for _ in range(100):
            due = self.core.next_deadline()
            if due >= until:
                return
            self.core.tick(max(due, self.now))
            if self.core.next_deadline() <= due:  # a deadline in the past not cleared: tick once more, not forever
                self.core.tick(max(due, self.now))
                return

    def goal(self, **fields: object) -> bytes:
        return msgspec.json.encode(fields)

    def until_done(self, timeout: float = 60.0) -> None:
        end = self.now + timeout
        while self.core.goals.current is not None and self.now < end:
            self.run(PERIOD)


def ended(bench: Bench) -> NavFeedback:
    return next(f for f in reversed(bench.out.feedback) if f.state.done)


# ----------------------------------------------------------------------------------------------- goals that arrive


def test_the_first_tick_publishes_the_map_pose_and_the_parameters() -> None:
    bench = Bench(map_pose=MapPose(0.0, 1.0, 2.0, 0.5, "site"))
    assert [(m.x, m.y, m.yaw, m.map) for m in bench.out.map_poses] == [(1.0, 2.0, 0.5, "site")]
    assert len(bench.out.params) == 1 and bench.out.params[0].params[0].name == "max_speed"
    assert bench.core.map_pose().map == "site" and bench.core.params().stamp == 1.8e9


def test_a_goal_on_the_map_is_reached_with_feedback_at_10_hz_and_a_result() -> None:
    bench = Bench(map_pose=MapPose(0.0, 10.0, 5.0, math.pi / 2))  # odom's origin at (10, 5) on the map, turned left
    reply = bench.core.on_goal(bench.goal(x=10.0, y=6.0, yaw=0.0, goal_id=GOAL_A), bench.now)  # 1 m ahead of the robot
    assert reply.accepted and reply.goal_id == GOAL_A and reply.reason == ""
    bench.core.tick(bench.now)  # the edge ticks at the deadline: the first feedback at once
    start, poses_before = bench.now, len(bench.out.twists)
    bench.until_done()
    result = bench.core.on_result(b"", bench.now)
    assert result.found and result.state is GoalState.SUCCEEDED and result.goal_id == GOAL_A, result
    assert result.pose is not None and result.goal is not None and result.pose.frame == "map"
    assert math.hypot(result.pose.x - 10.0, result.pose.y - 6.0) <= 0.01 and abs(result.pose.yaw) <= math.radians(1)
    assert math.hypot(bench.robot.x - 1.0, bench.robot.y) <= 0.01  # in odom: 1 m ahead
    running = [f for f in bench.out.feedback if not f.state.done]
    assert running[0].state is GoalState.ACCEPTED and running[-1].state is GoalState.EXECUTING
    assert len(running) >= 5 * (bench.now - start) - 1  # >= 5 Hz (10 Hz by default)
    assert len(running) == pytest.approx(10 * (bench.now - start), abs=2)
    last = ended(bench)
    assert last.state is GoalState.SUCCEEDED and last.eta == 0.0 and last.goal_id == GOAL_A and last.pose.frame == "map"
    assert sum(f.state.done for f in bench.out.feedback) == 1
    assert running[1].eta == pytest.approx(bench.now - start, rel=0.2)  # the ETA tracked the truth
    assert all(f.recoveries == 0 for f in bench.out.feedback)
    assert len(bench.out.twists) - poses_before == pytest.approx((bench.now - start) / PERIOD, abs=3)  # one twist per pose
    assert bench.out.errors == []
    twists = len(bench.out.twists)
    bench.run(2.0)
    assert len(bench.out.twists) == twists  # nothing after it arrived


def test_a_goal_in_odom_and_moves_run_on_the_same_controller() -> None:
    bench = Bench(map_pose=MapPose(0.0, 3.0, 3.0, 1.0))
    assert bench.core.on_goal(bench.goal(x=0.5, y=0.0, frame="odom"), bench.now).accepted
    bench.until_done()
    assert ended(bench).state is GoalState.SUCCEEDED and ended(bench).pose.frame == "odom"
    reply = bench.core.on_move(b'{"angle": 1.5707963}', bench.now)
    assert reply.accepted and reply.goal_id is not None and len(reply.goal_id) == 32
    bench.until_done()
    assert ended(bench).state is GoalState.SUCCEEDED and bench.robot.yaw == pytest.approx(math.pi / 2, abs=math.radians(1))
    assert bench.core.on_move(b'{"distance": -0.3}', bench.now).accepted  # backwards, facing where it faced
    bench.until_done()
    assert (bench.robot.x, bench.robot.y) == pytest.approx((0.5, -0.3), abs=0.01)
    assert bench.robot.yaw == pytest.approx(math.pi / 2, abs=math.radians(1))
    assert bench.core.on_move(b"{}", bench.now).accepted  # nothing to do: done at once
    bench.run(0.1)
    assert ended(bench).state is GoalState.SUCCEEDED


def test_set_pose_places_odom_on_the_map_and_a_map_goal_follows() -> None:
    bench = Bench()
    assert bench.core.on_goal(bench.goal(x=2.0, y=0.0, frame="map"), bench.now).accepted
    bench.run(2.0)
    odom_x = bench.robot.x
    placed = bench.core.on_set_pose(b'{"x": 1.0, "y": 1.0, "yaw": 0.0}', bench.now)  # it was at (odom_x, 0): shifted
    assert placed.by == "robot/nav/set_pose" and bench.out.map_poses[-1] is placed
    assert (placed.x, placed.y) == pytest.approx((1.0 - odom_x, 1.0), abs=0.01)
    bench.until_done()
    assert ended(bench).state is GoalState.SUCCEEDED
    # (2, 0) on the map is now (2 - placed.x, -1) in odom
    assert (bench.robot.x, bench.robot.y) == pytest.approx((2.0 - placed.x, -1.0), abs=0.011)
    with pytest.raises(PayloadError, match="not in frame 'odom'"):
        bench.core.on_set_pose(b'{"x": 1, "y": 1, "frame": "odom"}', bench.now)
    with pytest.raises(PayloadError, match="not a JSON object"):
        bench.core.on_set_pose(b"here", bench.now)
    assert [e.key for e in bench.out.errors] == ["robot/nav/set_pose"] * 2


# ------------------------------------------------------------------------------------------- bad input: its sentence


@pytest.mark.parametrize(
    ("payload", "words"),
    [
        (None, "payload is empty"),
        (b"", "payload is empty"),
        (b"go left", "not a JSON object"),
        (b'{"x": NaN, "y": 0}', "not valid JSON"),
        (b'{"x": 1e999, "y": 0}', "not finite"),
        (b'{"x": "1", "y": 0}', "Expected `float`, got `str`"),
        (b'{"x": 1, "Y": 2}', "unknown field `Y`"),
        (b'{"x": 1}', "missing required field `y`"),
        (b'{"x": 1, "y": 0, "goal_id": "42"}', "goal_id"),
        (b'{"x": 10000, "y": 0}', "goal is 10000.0 m from the robot, farther than max_goal_distance (100 m)"),
        (b'{"x": 1, "y": 0, "frame": "floor2"}', "goal in another map: frame 'floor2' is neither this robot's map 'map' nor 'odom'"),
        (b'{"x": 50, "y": 0}', "goal (50.00, 0.00) on the map is outside the geofence x -20..20, y -10..10"),
    ],
)
def test_a_bad_goal_is_refused_with_its_sentence_reported_and_nothing_moves(payload: bytes | None, words: str) -> None:
    bench = Bench(geofence=(-20.0, -10.0, 20.0, 10.0))
    reply = bench.core.on_goal(payload, bench.now)
    assert not reply.accepted and words in reply.reason
    assert [e.key for e in bench.out.errors] == ["robot/nav/goal"] and words in bench.out.errors[0].reason
    assert bench.out.errors[0].source == "nav"
    bench.run(0.5)
    assert bench.out.twists == [] and bench.core.goals.current is None


@pytest.mark.parametrize(
    ("setup", "words"),
    [
        (lambda b: b.core.on_health(health(estop=True), b.now), "robot is e-stopped (e-stop engaged since"),
        (lambda b: b.core.on_alive("gateway", False, b.now), "robot unreachable: the gateway is gone"),
        (lambda b: b.core.on_health(health(link="down"), b.now), "robot unreachable: the gateway's control link is down: cannot connect"),
        (lambda b: setattr(b, "poses", False) or b.run(1.0), "odometry not running: the last pose is 1.0 s old"),
    ],
    ids=["e-stopped", "gateway gone", "link down", "no poses"],
)
def test_a_goal_the_robot_cannot_follow_is_refused(setup: object, words: str) -> None:
    bench = Bench()
    setup(bench)  # type: ignore[operator]
    for query in (bench.core.on_goal, bench.core.on_move):
        reply = query(b'{"x": 1, "y": 0}' if query == bench.core.on_goal else b'{"distance": 1}', bench.now)
        assert not reply.accepted and words in reply.reason, reply
    assert bench.out.twists == []


def test_no_pose_yet_and_no_health_yet_are_refused() -> None:
    out = Out()
    core = NavCore(NavParams(), KEYS, out, map_pose=MapPose(0.0, 0.0, 0.0, 0.0))
    assert "no health report from the gateway yet" in core.on_goal(b'{"x": 1, "y": 0}', 0.0).reason
    core.on_health(health(), 0.0)
    assert core.on_goal(b'{"x": 1, "y": 0}', 0.0).reason == "odometry not running: no pose received yet"
    assert "no pose" in core.on_move(b'{"angle": 1}', 0.0).reason
    with pytest.raises(PayloadError, match="no pose yet"):
        core.on_set_pose(b'{"x": 1, "y": 1}', 0.0)


def test_ids_cancels_results_moves_and_params_refuse_with_sentences() -> None:
    bench = Bench()
    assert bench.core.on_goal(bench.goal(x=1.0, y=0.0, goal_id=GOAL_A), bench.now).accepted
    again = bench.core.on_goal(bench.goal(x=2.0, y=0.0, goal_id=GOAL_A), bench.now)
    assert not again.accepted and again.goal_id == GOAL_A and "taken by an earlier goal that is running" in again.reason
    unknown = bench.core.on_cancel(bench.goal(goal_id=GOAL_B), bench.now)
    assert unknown.canceled == [] and f"no goal {GOAL_B}" in unknown.reason
    assert bench.core.on_cancel(b'{"id": 1}', bench.now).reason.startswith("invalid NavCancel: ")
    missing = bench.core.on_result(bench.goal(goal_id=GOAL_B), bench.now)
    assert not missing.found and missing.goal_id == GOAL_B and "no goal" in missing.reason
    assert "invalid NavResultQuery" in bench.core.on_result(b"[]", bench.now).reason
    assert "not both" in bench.core.on_move(b'{"distance": 1, "angle": 1}', bench.now).reason
    assert "at most 12.57 rad (two turns)" in bench.core.on_move(b'{"angle": 100}', bench.now).reason
    assert "farther than max_goal_distance" in bench.core.on_move(b'{"distance": -500}', bench.now).reason
    bad = bench.core.on_params_set(b'{"max_speed": 1}', bench.now)
    assert (
        bad.results[0].successful is False and "unknown field `max_speed`" in bad.results[0].reason and '"values"' in bad.results[0].reason
    )
    keys = {e.key for e in bench.out.errors}
    assert keys == {"robot/nav/goal", "robot/nav/cancel", "robot/nav/result", "robot/nav/move", "robot/nav/params/set"}
    assert bench.core.goals.current is not None and bench.core.goals.current.goal_id == GOAL_A  # still running


@settings(max_examples=200, deadline=None)
@given(
    payload=st.one_of(
        st.binary(max_size=64),
        st.text(max_size=64).map(str.encode),
        st.dictionaries(
            st.sampled_from(["x", "y", "yaw", "frame", "goal_id", "distance", "angle", "values", "z"]),
            st.one_of(st.floats(), st.text(max_size=8), st.integers(), st.none()),
        ).map(msgspec.json.encode),
    )
)
def test_no_payload_crashes_a_query_or_moves_the_robot(payload: bytes) -> None:
    bench = Bench(max_goal_distance=0.5)
    bench.core.on_health(health(estop=True), bench.now)  # whatever is accepted cannot drive
    bench.core.on_goal(payload, bench.now)
    bench.core.on_move(payload, bench.now)
    bench.core.on_cancel(payload, bench.now)
    bench.core.on_result(payload, bench.now)
    bench.core.on_params_set(payload, bench.now)
    bench.core.on_pose(payload, bench.now)
    bench.core.on_health(payload, bench.now)
    bench.core.on_driver(payload, bench.now)
    bench.core.on_gateway_params(payload, bench.now)
    try:
        bench.core.on_set_pose(payload, bench.now)
    except PayloadError:
        pass
    bench.core.tick(bench.now + 1.0)
    assert bench.out.twists == []


# ------------------------------------------------------------------------------------------ goals that end early


def test_a_new_goal_preempts_the_running_one_which_ends_canceled() -> None:
    bench = Bench()
    assert bench.core.on_goal(bench.goal(x=3.0, y=0.0, goal_id=GOAL_A), bench.now).accepted
    bench.run(3.0)
    twists = len(bench.out.twists)
    assert bench.core.on_goal(bench.goal(x=0.5, y=0.5, goal_id=GOAL_B), bench.now).accepted
    first = bench.core.on_result(bench.goal(goal_id=GOAL_A), bench.now)
    assert first.state is GoalState.CANCELED and first.reason == f"preempted by goal {GOAL_B}"
    assert ended(bench).goal_id == GOAL_A and ended(bench).reason == f"preempted by goal {GOAL_B}"
    assert len(bench.out.twists) == twists  # no zero twist in between: the new goal drives on from the speed it has
    bench.until_done()
    assert bench.core.on_result(None, bench.now).state is GoalState.SUCCEEDED
    assert math.hypot(bench.robot.x - 0.5, bench.robot.y - 0.5) <= 0.01
    speeds = [t.linear.x for t in bench.out.twists[twists - 1 : twists + 2]]
    assert abs(speeds[1] - speeds[0]) <= 0.5 * PERIOD + 1e-9  # braked within the acceleration limit


def test_a_flood_of_goals_leaves_the_last_one_running_and_every_other_accounted_for() -> None:
    bench = Bench()
    ids = [f"{n:032x}" for n in range(300)]
    for goal_id in ids:
        assert bench.core.on_goal(bench.goal(x=1.0, y=0.5, goal_id=goal_id), bench.now).accepted
    assert bench.core.goals.current is not None and bench.core.goals.current.goal_id == ids[-1]
    assert bench.core.on_result(bench.goal(goal_id=ids[-2]), bench.now).reason == f"preempted by goal {ids[-1]}"
    assert not bench.core.on_result(bench.goal(goal_id=ids[0]), bench.now).found  # the last 100 are remembered
    bench.until_done()
    assert bench.core.on_result(None, bench.now).state is GoalState.SUCCEEDED


def run_then(bench: Bench, seconds: float = 1.0) -> int:
    assert bench.core.on_goal(bench.goal(x=2.0, y=0.0, goal_id=GOAL_A), bench.now).accepted
    bench.run(seconds)
    assert bench.robot.v > 0.1
    return len(bench.out.twists)


def assert_stopped_once(bench: Bench, twists: int, state: GoalState, words: str) -> None:
    """The goal ended ``state`` for ``words``; exactly one zero twist since ``twists``, and nothing ever after."""
    result = bench.core.on_result(None, bench.now)
    assert result.state is state and words in result.reason, result
    assert ended(bench).state is state and words in ended(bench).reason
    assert bench.out.twists[twists:] == [Twist()]
    bench.core.on_health(health(), bench.now)  # an e-stop released, the link back, the nav driving again...
    bench.core.on_driver(encode(DriverChange(1e12, "nav", None, "")), bench.now)
    bench.core.on_alive("gateway", True, bench.now)
    bench.poses = True
    bench.run(3.0)
    assert bench.out.twists[twists:] == [Twist()]  # ...and nothing moves until a new goal


def test_an_estop_aborts_the_goal_with_its_reason_and_nothing_moves_after_the_release() -> None:
    bench = Bench()
    twists = run_then(bench)
    bench.core.on_health(health(estop=True), bench.now)
    assert_stopped_once(bench, twists, GoalState.ABORTED, "e-stop engaged since")
    assert any("aborted: e-stop engaged" in e.reason for e in bench.out.errors)


def test_a_stale_pose_stops_the_robot_and_aborts() -> None:
    bench = Bench()
    twists = run_then(bench)
    bench.poses = False
    bench.run(0.26)
    assert bench.core.goals.current is not None
    bench.run(0.06)
    assert_stopped_once(bench, twists, GoalState.ABORTED, "pose stale: no pose from the odometry for 0.30 s")


@pytest.mark.parametrize(
    ("event", "words"),
    [
        (lambda b: b.core.on_alive("gateway", False, b.now), "robot unreachable: the gateway is gone"),
        (lambda b: b.core.on_health(health(link="connecting"), b.now), "robot unreachable: the gateway's control link is connecting"),
    ],
    ids=["gateway gone", "link down"],
)
def test_losing_the_robot_aborts(event: object, words: str) -> None:
    bench = Bench()
    twists = run_then(bench)
    event(bench)  # type: ignore[operator]
    assert_stopped_once(bench, twists, GoalState.ABORTED, words)


def test_an_override_longer_than_its_timeout_aborts_a_shorter_one_does_not() -> None:
    bench = Bench()
    twists = run_then(bench)
    bench.core.on_driver(encode(DriverChange(1.8e9 + bench.now, "teleop", "nav", "teleop outranks nav")), bench.now)
    bench.run(1.5)
    bench.core.on_driver(encode(DriverChange(1.8e9 + bench.now, "nav", "teleop", "teleop timed out")), bench.now)
    bench.core.on_driver(encode(DriverChange(1.8e9 + bench.now - 0.5, "teleop", "nav", "late news")), bench.now)  # older: ignored
    bench.run(1.0)
    assert bench.core.goals.current is not None
    twists = len(bench.out.twists)
    bench.core.on_driver(encode(DriverChange(1.8e9 + bench.now, "teleop", "nav", "teleop outranks nav")), bench.now)
    bench.run(1.98)
    assert bench.core.goals.current is not None
    bench.run(0.04)
    assert_stopped_once(
        bench, len(bench.out.twists) - 1, GoalState.ABORTED, "overridden: teleop drives instead of the navigation for 2.0 s"
    )
    assert len(bench.out.twists) > twists


def test_a_lock_that_blocks_the_navigation_counts_as_an_override() -> None:
    bench = Bench(override_timeout=0.5)
    run_then(bench)
    bench.core.on_health(health(source=None, stamp=1.8e9 + bench.now), bench.now)  # the health says nobody drives
    bench.run(0.6)
    assert "nobody drives" in bench.core.on_result(None, bench.now).reason


def test_a_robot_that_does_not_move_aborts_for_no_progress() -> None:
    bench = Bench(no_progress_timeout=1.0)
    twists = run_then(bench, 0.5)
    bench.moves = False
    bench.run(1.2)
    assert_stopped_once(bench, len(bench.out.twists) - 1, GoalState.ABORTED, "no progress: ")
    assert len(bench.out.twists) > twists


def test_cancel_stops_the_robot_with_one_zero_twist() -> None:
    bench = Bench()
    assert bench.core.on_cancel(None, bench.now).reason == "no goal is running"
    twists = run_then(bench)
    reply = bench.core.on_cancel(b"", bench.now)
    assert reply.canceled == [GOAL_A] and reply.reason == ""
    assert_stopped_once(bench, twists, GoalState.CANCELED, "canceled by a client")
    late = bench.core.on_cancel(bench.goal(goal_id=GOAL_A), bench.now)
    assert late.canceled == [] and late.reason == f"goal {GOAL_A} is not running: it ended canceled"
    assert not any("canceled" in e.reason for e in bench.out.errors)  # a cancel is no error


def test_a_goal_canceled_before_its_first_pose_sends_nothing() -> None:
    bench = Bench()
    assert bench.core.on_goal(b'{"x": 1, "y": 1}', bench.now).accepted
    assert bench.core.on_cancel(None, bench.now).canceled
    bench.run(1.0)
    assert bench.out.twists == []


# --------------------------------------------------------------------------------------------------- parameters


def test_parameters_change_live_and_refuse_out_of_range() -> None:
    bench = Bench()
    reply = bench.core.on_params_set(b'{"values": {"max_speed": 0.2, "max_turn": 99, "feedback_hz": 20}}', bench.now)
    assert [(r.name, r.successful) for r in reply.results] == [("max_speed", True), ("max_turn", False), ("feedback_hz", True)]
    assert reply.results[1].reason == "max_turn must be within 0.05..8, got 99"
    assert bench.out.params[-1].changed == ["max_speed", "feedback_hz"]
    assert {p.name: p.value for p in reply.params.params}["effective.max_speed"] == 0.2
    assert [e.reason for e in bench.out.errors] == ["max_turn must be within 0.05..8, got 99"]
    assert bench.core.nav_params.max_speed == 0.2
    start = bench.now
    assert bench.core.on_goal(b'{"x": 1.5, "y": 0}', bench.now).accepted
    bench.until_done()
    assert max(t.linear.x for t in bench.out.twists) == pytest.approx(0.2)
    running = [f for f in bench.out.feedback if not f.state.done]
    assert len(running) >= 19 * (bench.now - start)  # 20 Hz


def test_the_gateways_limits_bound_a_goal() -> None:
    bench = Bench()
    limits = GatewayParams(0.0, [Param("max_wheel_speed", "double", 0.15), Param("wheel_separation", "double", 0.5, read_only=True)])
    bench.core.on_gateway_params(encode(limits), bench.now)
    assert bench.out.params[-1].changed[0] == "effective.max_speed"
    bench.core.on_gateway_params(encode(limits), bench.now)  # the same again: nothing to publish
    assert len(bench.out.params) == 2
    assert bench.core.on_goal(b'{"x": 1, "y": 1}', bench.now).accepted
    bench.until_done()
    assert max(abs(t.linear.x) + abs(t.angular.z) * 0.25 for t in bench.out.twists) <= 0.15 + 1e-9
    assert bench.core.on_result(None, bench.now).state is GoalState.SUCCEEDED


def test_deadlines_are_the_feedback_the_pose_timeout_and_report_summaries() -> None:
    bench = Bench()
    assert bench.core.next_deadline() == math.inf  # nothing runs
    assert bench.core.on_goal(b'{"x": 1, "y": 0}', bench.now).accepted
    assert bench.core.next_deadline() == bench.now  # the first feedback at once
    bench.core.tick(bench.now)
    assert bench.core.next_deadline() == pytest.approx(bench.now + 0.1)  # the next feedback (10 Hz)
    bench.core.on_params_set(b'{"values": {"feedback_hz": 5, "pose_timeout": 0.15}}', bench.now)
    bench.core.tick(bench.now + 0.1)
    assert bench.core.next_deadline() == pytest.approx(bench.now + 0.15)  # the pose timeout comes before the feedback now
    for _ in range(40):
        bench.core.on_goal(b"junk", bench.now)  # rate-limited: a summary is due later
    assert bench.core.on_cancel(None, bench.now).canceled
    assert bench.core.next_deadline() == pytest.approx(bench.now + 1.0)
