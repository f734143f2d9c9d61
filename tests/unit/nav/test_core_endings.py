"""NavCore's goals that end early: preempted, canceled, aborted (e-stop, stale pose, robot lost, override, no progress),
each with its reason, one zero twist, and nothing moving after it until a new goal."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from blackmetal.schemas import DriverChange, GoalState, NavFeedback, Twist, encode, make_pose

from .bench import GOAL_A, GOAL_B, Bench, ended, health
from .kinematics import PERIOD

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
    assert len(bench.out.twists) == twists + 1  # no zero twist in between: the new goal's first command at once
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


def test_an_odometry_reset_during_a_goal_aborts_it() -> None:
    bench = Bench()
    twists = run_then(bench)
    bench.robot.x += 1.0  # as a reset to another pose looks from here
    bench.run(PERIOD)
    assert_stopped_once(bench, twists, GoalState.ABORTED, "odometry jumped 1.0")


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


def test_a_goal_drives_at_once_and_a_cancel_right_after_stops_it() -> None:
    """The first command goes out on acceptance (from the latest pose), not a pose later; a cancel then sends one zero."""
    bench = Bench()
    assert bench.core.on_goal(b'{"x": 1, "y": 1}', bench.now).accepted
    assert len(bench.out.twists) == 1 and bench.out.twists[0].angular.z == pytest.approx(2.0 * PERIOD)  # turning left
    assert bench.core.on_result(None, bench.now).state is GoalState.EXECUTING
    assert bench.core.on_cancel(None, bench.now).canceled
    bench.run(1.0)
    assert bench.out.twists[1:] == [Twist()]


#: What may happen, goals and time more often than the rest.
ACTIONS = [
    *["goal"] * 4,
    *["move", "cancel", "cancel_other", "estop", "release", "teleop", "nav_drives", "link_down", "link_up"],
    *["gateway_gone", "gateway_back", "poses_stop", "poses_go"],
    *["run"] * 4,
    "run_long",
]


@settings(max_examples=120, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(ACTIONS), st.floats(-3.0, 3.0), st.floats(-3.0, 3.0)), min_size=6, max_size=30))
def test_any_sequence_ends_every_goal_once_and_stops_the_robot_after_each_early_end(steps: list[tuple[str, float, float]]) -> None:
    """Whatever happens in whatever order: at most one goal runs, each accepted goal ends once (one last feedback), and
    after a goal ends early the robot gets at most one zero twist and nothing else until the next goal is accepted."""
    bench = Bench(override_timeout=1.0)
    b, core = bench, bench.core
    accepted: list[str] = []
    for action, x, y in steps:
        if action == "goal" or action == "move":
            mark = len(b.out.log)  # what the goal sends on acceptance comes after its mark
            reply = core.on_goal(b.goal(x=x, y=y), b.now) if action == "goal" else core.on_move(b.goal(distance=x / 3), b.now)
            if reply.accepted:
                assert reply.goal_id is not None
                accepted.append(reply.goal_id)
                b.out.log.insert(mark, ("accepted", reply.goal_id))
        elif action == "cancel":
            core.on_cancel(None, b.now)
        elif action == "cancel_other":
            core.on_cancel(b.goal(goal_id="c" * 32), b.now)
        elif action in ("estop", "release", "link_down", "link_up"):
            core.on_health(
                health(estop=action == "estop", link="down" if action == "link_down" else "connected", source="nav", stamp=1.8e9 + b.now),
                b.now,
            )
        elif action in ("teleop", "nav_drives"):
            core.on_driver(encode(DriverChange(1.8e9 + b.now, "teleop" if action == "teleop" else "nav", None, "")), b.now)
        elif action in ("gateway_gone", "gateway_back"):
            core.on_alive("gateway", action == "gateway_back", b.now)
        elif action in ("poses_stop", "poses_go"):
            b.poses = action == "poses_go"
        else:
            b.run(0.5 if action == "run" else 3.0)
    b.run(0.2)
    finals = [f for f in b.out.feedback if f.state.done]
    assert sorted(f.goal_id for f in finals) == sorted(set(accepted) - ({core.goals.current.goal_id} if core.goals.current else set()))
    assert all(f.reason or f.state is GoalState.SUCCEEDED for f in finals)
    # after an early end (not a preemption: the next goal drives on), one zero twist at most until a goal is accepted
    quiet, zeros = False, 0
    for item in b.out.log:
        if isinstance(item, tuple):
            quiet, zeros = False, 0
        elif isinstance(item, NavFeedback) and item.state.done and not item.reason.startswith("preempted"):
            quiet, zeros = True, 0
        elif isinstance(item, Twist) and quiet:
            zeros += 1
            assert item == Twist() and zeros == 1, "the robot was commanded after its goal ended"
    event(f"{len(finals)} goals ended, {sum(f.state is GoalState.ABORTED for f in finals)} aborted")


finite = st.floats(allow_nan=False, allow_infinity=False)


@settings(max_examples=150, deadline=None)
@given(poses=st.lists(st.tuples(finite, finite, finite, st.floats(-0.05, 1.0)), min_size=1, max_size=30))
def test_whatever_poses_the_odometry_sends_the_core_commands_only_finite_twists_within_the_limits(
    poses: list[tuple[float, float, float, float]],
) -> None:
    """Poses anywhere (1e308 away, jumping, stamps going back): no exception, and every twist finite and within the limits."""
    bench = Bench()
    assert bench.core.on_goal(b'{"x": 1, "y": 0.5, "yaw": 2}', bench.now).accepted
    stamp = 1.8e9
    for x, y, yaw, gap in poses:
        stamp += gap
        bench.now += max(gap, 0.0)
        bench.core.on_pose(encode(make_pose(stamp, x, y, yaw)), bench.now)
        bench.core.tick(bench.now)
    for twist in bench.out.twists:
        assert math.isfinite(twist.linear.x) and math.isfinite(twist.angular.z)
        assert abs(twist.linear.x) <= 0.3 + 1e-9 and abs(twist.angular.z) <= 1.2 + 1e-9


@settings(max_examples=60, deadline=None)
@given(steps=st.lists(st.tuples(st.floats(-0.015, 0.015), st.floats(-0.015, 0.015), st.floats(-0.06, 0.06)), min_size=1, max_size=120))
def test_a_wandering_pose_gets_finite_twists_within_the_limits_and_their_accelerations(steps: list[tuple[float, float, float]]) -> None:
    """Poses that move in ways the commands do not explain (slip, noise, a push), but never jump: the controller
    keeps every twist finite, within the speed limits, and each within one period's acceleration of the one before."""
    bench = Bench(no_progress_timeout=600.0, override_timeout=60.0)  # nothing ends it but arriving
    assert bench.core.on_goal(b'{"x": 0.4, "y": -0.3, "yaw": 2}', bench.now).accepted
    x = y = yaw = 0.0
    for dx, dy, dyaw in steps:
        x, y, yaw = x + dx, y + dy, yaw + dyaw
        bench.now += PERIOD
        bench.core.on_pose(encode(make_pose(1.8e9 + bench.now, x, y, yaw)), bench.now)
        bench.core.tick(bench.now)
    twists = [(0.0, 0.0)] + [(t.linear.x, t.angular.z) for t in bench.out.twists]
    for (v0, w0), (v1, w1) in itertools.pairwise(twists):
        assert math.isfinite(v1) and math.isfinite(w1) and abs(v1) <= 0.3 + 1e-9 and abs(w1) <= 1.2 + 1e-9
        # within the acceleration over the period the core measured (from stamps near 1.8e9 s: good to 1e-6 s)
        assert (v1, w1) == (0.0, 0.0) or (abs(v1 - v0) <= 0.5 * PERIOD + 1e-6 and abs(w1 - w0) <= 2.0 * PERIOD + 1e-6)
