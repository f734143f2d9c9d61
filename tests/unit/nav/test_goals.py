"""Goals' lives: one at a time, preemption, ids, the results memory; and the map frame's arithmetic."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from blackmetal.nav.goals import GoalRecord, Goals, jumped, map_to_odom, odom_to_map, placed, refusal, robot_trouble, wrap
from blackmetal.schemas import GatewayHealth, GoalState, LinkHealth, MapPose, PlanarPose, make_pose


def record(goal_id: str, at: float = 0.0) -> GoalRecord:
    return GoalRecord(goal_id, PlanarPose(1.0, 2.0, 0.0, "map"), at)


def test_a_goal_is_accepted_then_executes_then_ends_with_its_reason() -> None:
    goals = Goals()
    assert goals.accept(record("a" * 32, 1.0), 1.0) is None
    assert goals.current is not None and goals.current.state is GoalState.ACCEPTED
    assert goals.start().state is GoalState.EXECUTING
    done = goals.finish(GoalState.ABORTED, "e-stop engaged", 3.5)
    assert (done.state, done.reason, done.elapsed(99.0)) == (GoalState.ABORTED, "e-stop engaged", 2.5)
    assert goals.current is None and goals.latest() is done
    result = done.result(99.0)
    assert result.found and result.goal_id == "a" * 32 and result.state is GoalState.ABORTED and result.elapsed == 2.5


def test_a_new_goal_preempts_the_running_one() -> None:
    goals = Goals()
    goals.accept(record("a" * 32), 0.0)
    goals.start()
    preempted = goals.accept(record("b" * 32), 1.0)
    assert preempted is not None and preempted.goal_id == "a" * 32
    assert preempted.state is GoalState.CANCELED and preempted.reason == f"preempted by goal {'b' * 32}"
    assert goals.current is not None and goals.current.goal_id == "b" * 32


def test_illegal_transitions_are_programming_errors() -> None:
    goals = Goals()
    with pytest.raises(ValueError, match="no goal is running"):
        goals.finish(GoalState.SUCCEEDED, "", 0.0)
    goals.accept(record("a" * 32), 0.0)
    with pytest.raises(ValueError, match="ends succeeded, canceled or aborted"):
        goals.finish(GoalState.EXECUTING, "", 0.0)
    with pytest.raises(ValueError, match="already known"):
        goals.accept(record("a" * 32), 0.0)
    late = record("c" * 32)
    late.state = GoalState.SUCCEEDED
    with pytest.raises(ValueError, match="must be accepted"):
        goals.accept(late, 0.0)


def test_ids_are_made_fresh_and_a_known_one_is_refused() -> None:
    made = iter(["a" * 32, "a" * 32, "b" * 32])
    goals = Goals(new_id=lambda: next(made))
    first = goals.new_id()
    goals.accept(record(first), 0.0)
    assert goals.new_id() == "b" * 32  # the repeat was skipped
    reason = goals.refusal_of_id("a" * 32)
    assert reason is not None and "is taken by an earlier goal that is running" in reason
    goals.finish(GoalState.SUCCEEDED, "", 1.0)
    assert "ended succeeded" in (goals.refusal_of_id("a" * 32) or "")
    assert goals.refusal_of_id("f" * 32) is None
    real = Goals().new_id()
    assert len(real) == 32 and int(real, 16) >= 0


def test_the_last_hundred_goals_are_remembered() -> None:
    goals = Goals()
    ids = [f"{n:032x}" for n in range(150)]
    for n, goal_id in enumerate(ids):
        goals.accept(record(goal_id, float(n)), float(n))
    assert len(goals) == 100
    assert goals.find(ids[49]) is None and goals.find(ids[50]) is not None
    assert goals.current is not None and goals.current.goal_id == ids[-1]
    assert all(goals.find(i).state is GoalState.CANCELED for i in ids[50:-1])  # type: ignore[union-attr]


def test_map_and_odom_transforms_are_inverse() -> None:
    m = MapPose(0.0, 10.0, -5.0, math.pi / 2)
    assert odom_to_map(m, 1.0, 0.0, 0.0) == pytest.approx((10.0, -4.0, math.pi / 2))
    assert map_to_odom(m, 10.0, -4.0, math.pi / 2) == pytest.approx((1.0, 0.0, 0.0), abs=1e-12)


finite = st.floats(-50, 50)


@given(finite, finite, st.floats(-4, 4), finite, finite, st.floats(-4, 4), st.floats(-4, 4), st.floats(-4, 4))
def test_placing_odom_puts_the_robot_where_it_was_said_to_be(
    ax: float, ay: float, ayaw: float, ox: float, oy: float, oyaw: float, px: float, py: float
) -> None:
    x, y, yaw = placed((ax, ay, ayaw), (ox, oy, oyaw))
    m = MapPose(0.0, x, y, yaw)
    assert odom_to_map(m, ox, oy, oyaw)[:2] == pytest.approx((ax, ay), abs=1e-9)
    assert abs(wrap(odom_to_map(m, ox, oy, oyaw)[2] - ayaw)) < 1e-9
    back = map_to_odom(m, *odom_to_map(m, px, py, 0.3))
    assert back[:2] == pytest.approx((px, py), abs=1e-9)


def health(**fields: object) -> GatewayHealth:
    link = LinkHealth(str(fields.pop("link", "connected")), reason=fields.pop("why", None))  # type: ignore[arg-type]
    return GatewayHealth(0.0, link, LinkHealth("connected"), **fields)  # type: ignore[arg-type]


def test_what_keeps_the_robot_from_a_goal_is_said_in_one_sentence() -> None:
    assert robot_trouble(None, None) is None and robot_trouble(health(), True) is None
    assert robot_trouble(health(estop=True, estop_since=0.0, estop_by="robot/estop"), True) == (
        "e-stop engaged since 1970-01-01 00:00:00 UTC by robot/estop"
    )
    assert robot_trouble(health(), False) == "robot unreachable: the gateway is gone (its liveliness token went away)"
    assert (
        robot_trouble(health(link="down", why="cannot connect"), None)
        == "robot unreachable: the gateway's control link is down: cannot connect"
    )
    ok = {"gateway": True, "odometry": True}
    assert refusal(health(), ok, 0.01, 0.3, "robot/estop/release") is None
    assert "release it on robot/estop/release, then send the goal again" in (
        refusal(health(estop=True), ok, 0.01, 0.3, "robot/estop/release") or ""
    )
    assert refusal(None, ok, 0.01, 0.3, "k") == "robot unreachable: no health report from the gateway yet"
    assert refusal(health(), ok, None, 0.3, "k") == "odometry not running: no pose received yet"
    assert refusal(health(), {"odometry": False}, 2.0, 0.3, "k") == (
        "odometry not running: the last pose is 2.0 s old (pose_timeout 0.3 s) (its liveliness token is gone)"
    )


def test_a_pose_that_no_motion_explains_is_a_jump() -> None:
    last = make_pose(100.0, 1.0, 1.0, 0.0)
    assert jumped(last, make_pose(100.02, 1.015, 1.0, 0.06), 0.02) is None  # 0.75 m/s, 3 rad/s: fast, but motion
    assert (
        jumped(last, make_pose(100.02, 0.0, 0.0, 0.0), 0.02)
        == "odometry jumped 1.41 m and 0 deg in 0.02 s (reset?): the goal's place in it is lost"
    )
    assert "and 90 deg" in (jumped(last, make_pose(100.02, 1.0, 1.0, math.pi / 2), 0.02) or "")
    assert jumped(last, make_pose(101.0, 1.9, 1.0, 0.0), 0.02) is None  # a second without poses: 0.9 m is possible
    assert jumped(last, make_pose(99.0, 1.2, 1.0, 0.0), 0.02) is not None  # stamps out of order: one period is allowed
