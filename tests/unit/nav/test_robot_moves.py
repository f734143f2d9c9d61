"""A relative move by the robot's own position control, the navigation's side (:mod:`blackmetal.nav.robot_moves`)."""

from __future__ import annotations

import json
import math

import pytest

from blackmetal import robot_model as model
from blackmetal.nav.robot_moves import (
    STALL_S,
    MoveProgress,
    RobotConstants,
    RobotMoveTracker,
    expected_duration,
    outcome,
    wheel_move,
    wheel_travels,
)
from blackmetal.schemas import GatewayParams, GoalState, MoveState, NavMove, Param, WheelMoveReply, WheelPosition

SIM = RobotConstants(position_moves=True, position_speed=0.3, wheel_separation=0.5, impulses_left=1000.0, impulses_right=1000.0)
MOVE_ID = "ab" * 16


def test_the_constants_come_from_the_gateways_parameters() -> None:
    params = GatewayParams(
        stamp=1.0,
        params=[
            Param("position_moves", "bool", True),
            Param("position_speed", "double", 0.25),
            Param("wheel_separation", "double", 0.52),
            Param("impulses_left", "double", 1010.0),
            Param("impulses_right", "integer", 1050),
            Param("max_wheel_speed", "double", 0.8),
        ],
    )
    assert RobotConstants.of(params) == RobotConstants(True, 0.25, 0.52, 1010.0, 1050.0)


def test_a_gateway_that_names_no_position_moves_has_none_and_bad_values_keep_the_nominal_ones() -> None:
    params = GatewayParams(
        stamp=1.0,
        params=[Param("position_moves", "string", "yes"), Param("position_speed", "double", -1.0), Param("impulses_left", "bool", True)],
    )
    constants = RobotConstants.of(params)
    assert constants == RobotConstants() and not constants.position_moves
    assert constants.impulses_left == model.IMPULSES_PER_METER_LEFT and constants.wheel_separation == model.WHEEL_SEPARATION


def test_a_distance_is_the_same_travel_on_both_wheels_and_an_angle_opposite_travels() -> None:
    assert wheel_travels(NavMove(distance=-1.5), SIM) == (-1.5, -1.5)
    left, right = wheel_travels(NavMove(angle=math.pi), SIM)
    assert (left, right) == pytest.approx((-math.pi * 0.25, math.pi * 0.25))  # positive turns left: the right wheel forward
    request = wheel_move(NavMove(angle=-1.0), SIM, MOVE_ID)
    assert (request.left, request.right, request.source, request.move_id) == (0.25, -0.25, "nav", MOVE_ID)
    assert expected_duration(NavMove(distance=3.0), SIM) == pytest.approx(10.0)
    assert expected_duration(NavMove(angle=1.2), SIM) == pytest.approx(1.0)


def position(
    left: int, right: int, state: MoveState = MoveState.RUNNING, target: tuple[int, int] = (1000, -1000), reason: str = ""
) -> WheelPosition:
    return WheelPosition(
        stamp=1.0,
        move_id=MOVE_ID,
        source="nav",
        state=state,
        left=left,
        right=right,
        start_left=0,
        start_right=0,
        target_left=target[0],
        target_right=target[1],
        elapsed=0.0,
        reason=reason,
    )


def accepted(move: NavMove, now: float = 0.0) -> RobotMoveTracker:
    tracker = RobotMoveTracker(move, SIM, now)
    assert tracker.on_reply(WheelMoveReply(True, MOVE_ID, left_impulses=1000, right_impulses=1000), now) is None
    return tracker


def test_the_progress_of_a_distance_counts_both_wheels_the_right_one_mirrored() -> None:
    tracker = accepted(NavMove(distance=1.0))
    progress = tracker.on_position(position(400, -400), 1.0)
    assert progress is not None and not progress.over
    assert progress.remaining == pytest.approx(0.6) and progress.fraction == pytest.approx(0.4) and progress.eta == pytest.approx(2.0)
    done = tracker.on_position(position(1000, -1000, MoveState.DONE), 3.4)
    assert done == MoveProgress(0.0, 1.0, 0.0, done=True)


def test_the_progress_of_a_turn_is_the_angle_left() -> None:
    quarter = math.pi / 2
    travel = round(quarter * 0.25 * 1000)
    tracker = accepted(NavMove(angle=quarter))
    progress = tracker.on_position(position(-travel // 2, -travel // 2, target=(-travel, -travel)), 0.5)
    assert (
        progress is not None
        and progress.remaining == pytest.approx(quarter / 2, abs=0.01)
        and progress.fraction == pytest.approx(0.5, abs=0.01)
    )


def test_another_moves_publication_is_not_this_ones() -> None:
    tracker = accepted(NavMove(distance=1.0))
    other = position(10, -10)
    other.move_id = "cd" * 16
    assert tracker.on_position(other, 0.1) is None
    assert RobotMoveTracker(NavMove(distance=1.0), SIM, 0.0).on_position(position(10, -10), 0.1) is None  # no reply yet


def test_a_refused_move_ends_with_the_gateways_reason() -> None:
    tracker = RobotMoveTracker(NavMove(distance=1.0), SIM, 0.0)
    reason = "emergency stop is engaged: a position move is refused"
    assert tracker.on_reply(WheelMoveReply(False, reason=reason), 0.0) == reason
    assert tracker.progress.ended and tracker.progress.reason == reason


def test_a_move_the_gateway_ended_ends_with_its_reason() -> None:
    tracker = accepted(NavMove(distance=1.0))
    tracker.on_position(position(300, -300), 1.0)
    progress = tracker.on_position(position(330, -330, MoveState.ENDED, reason="the e-stop is engaged"), 1.1)
    assert progress is not None and progress.ended and progress.reason == "the e-stop is engaged"
    assert progress.remaining == pytest.approx(0.67) and tracker.deadline() == math.inf


def test_wheels_that_stand_short_of_the_target_stall_and_a_silent_gateway_too() -> None:
    tracker = accepted(NavMove(distance=1.0))
    tracker.on_position(position(300, -300), 1.0)
    assert tracker.deadline() == 1.0 + STALL_S
    assert not tracker.check(1.0 + STALL_S - 0.01).over
    stalled = tracker.check(1.0 + STALL_S)
    assert stalled.stalled and stalled.reason == f"the wheels stood still for {STALL_S:g} s short of the target"
    silent = accepted(NavMove(distance=1.0), now=5.0)
    assert silent.check(5.0 + STALL_S).reason == "the gateway said nothing of the move"


def test_wheels_standing_at_the_target_are_done_though_the_done_publication_was_lost() -> None:
    tracker = accepted(NavMove(distance=1.0))
    tracker.on_position(position(999, -1001), 3.4)
    assert tracker.check(3.4 + STALL_S).done


def test_the_progress_follows_a_move_the_gateway_runs_on_the_simulator() -> None:
    from unit.gateway.test_core import Bench

    bench = Bench(position_moves=True)
    bench.connect()
    bench.run(0.5)
    params = RobotConstants.of(bench.conn.params_now())
    assert params.position_moves and params.impulses_left == model.IMPULSES_PER_METER_LEFT
    move = NavMove(angle=-math.pi / 2)
    tracker = RobotMoveTracker(move, params, bench.t)
    reply = bench.conn.on_wheel_move(
        json.dumps({"left": wheel_move(move, params).left, "right": wheel_move(move, params).right}).encode(), bench.t
    )
    assert tracker.on_reply(reply, bench.t) is None
    seen: list[MoveProgress] = []
    while not tracker.progress.over and bench.t < 5.0:
        bench.run(0.02)
        for message in bench.of(WheelPosition):
            progress = tracker.on_position(message, bench.t)
            if progress is not None and (not seen or progress != seen[-1]):
                seen.append(progress)
        bench.events.clear()
    assert tracker.progress.done and math.degrees(bench.robot.yaw) == pytest.approx(-90.0, abs=0.2)
    assert abs(tracker.progress.remaining) < 0.005
    etas = [p.eta for p in seen if not p.over]
    assert etas[0] == pytest.approx(expected_duration(move, params), abs=0.05) and etas == sorted(etas, reverse=True)


def test_the_goal_succeeds_at_the_target_and_aborts_with_the_reason_otherwise() -> None:
    assert outcome(MoveProgress(0.5, 0.5, 1.0)) is None
    assert outcome(MoveProgress(0.0, 1.0, 0.0, done=True)) == (GoalState.SUCCEEDED, "")
    ended = MoveProgress(0.6, 0.4, 0.0, ended=True, reason="the e-stop is engaged")
    assert outcome(ended) == (GoalState.ABORTED, "the robot's position move ended: the e-stop is engaged")
    stalled = MoveProgress(0.6, 0.4, 0.0, stalled=True, reason="the gateway said nothing of the move")
    assert outcome(stalled) == (GoalState.ABORTED, "the robot's position move ended: the gateway said nothing of the move")
