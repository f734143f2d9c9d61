"""The navigation's messages (:mod:`blackmetal.schemas.navigation`): what a client may send as a goal, a move, a cancel
or a set-pose, refused with where it is wrong; the states that end a goal. Round trips: test_messages.py's."""

from __future__ import annotations

import pytest

from blackmetal.schemas import GoalState, Keys, MapPose, NavCancel, NavGoal, NavMove, PayloadError, SetPose, decode
from blackmetal.schemas.keys import Delivery, delivery_of

GOAL_ID = "0123456789abcdef0123456789abcdef"


def test_a_goal_takes_x_and_y_and_defaults_to_the_map_and_any_heading() -> None:
    goal = decode(NavGoal, b'{"x": 1, "y": -2.5}')
    assert (goal.x, goal.y, goal.yaw, goal.frame, goal.goal_id) == (1.0, -2.5, None, "map", None)
    assert decode(NavGoal, b'{"x":0,"y":0,"yaw":3.1,"frame":"odom","goal_id":"%s"}' % GOAL_ID.encode()).goal_id == GOAL_ID


@pytest.mark.parametrize(
    ("kind", "payload", "reason"),
    [
        (NavGoal, b'{"x": 1}', "missing required field `y`"),
        (NavGoal, b'{"x": 1, "Y": 2}', "unknown field `Y`"),
        (NavGoal, b'{"x": NaN, "y": 0}', "invalid NavGoal"),
        (NavGoal, b'{"x": 1e999, "y": 0}', "not finite"),
        (NavGoal, b'{"x": "1", "y": 0}', "Expected `float`, got `str`"),
        (NavGoal, b'{"x": 1, "y": 0, "goal_id": "ABC"}', "matching regex '^[0-9a-f]{32}$' - at `$.goal_id`"),
        (NavGoal, b'{"x": 1, "y": 0, "frame": ""}', "length >= 1"),
        (NavMove, b'{"distance": 1, "angle": 1}', "a distance or an angle, not both"),
        (NavMove, b'{"meters": 1}', "unknown field `meters`"),
        (NavCancel, b'{"goal_id": 7}', "Expected `str | null`, got `int`"),
        (SetPose, b'{"x": 1}', "missing required field `y`"),
    ],
)
def test_what_a_client_sends_wrong_is_refused_with_where(kind: type, payload: bytes, reason: str) -> None:
    with pytest.raises(PayloadError) as refused:
        decode(kind, payload)
    assert reason in str(refused.value), str(refused.value)


def test_a_move_is_a_distance_or_an_angle_and_a_cancel_may_name_nothing() -> None:
    assert decode(NavMove, b'{"distance": -0.5}').distance == -0.5
    assert decode(NavMove, b'{"angle": 1.57}').angle == 1.57
    assert decode(NavCancel, b"{}").goal_id is None


def test_only_succeeded_canceled_and_aborted_end_a_goal() -> None:
    assert [state.value for state in GoalState if state.done] == ["succeeded", "canceled", "aborted"]


def test_the_navigation_keys_carry_their_messages_and_feedback_is_telemetry() -> None:
    keys = Keys("fleet/a")
    assert (keys.nav_goal, keys.alive_nav) == ("fleet/a/nav/goal", "fleet/a/alive/nav")
    assert keys.message_for(keys.nav_map_pose) is MapPose and keys.message_for(keys.nav_goal) is NavGoal
    assert delivery_of(keys.nav_feedback, keys.prefix) is Delivery.TELEMETRY
    assert delivery_of(keys.cmd_vel_of("nav"), keys.prefix) is Delivery.COMMAND
