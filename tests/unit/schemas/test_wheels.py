"""The position-move messages (:mod:`blackmetal.schemas.wheels`): what a client may put on ``wheels/move``."""

from __future__ import annotations

import pytest

from blackmetal.schemas import Keys, PayloadError, WheelMove, WheelMoveReply, WheelPosition, decode


def test_a_move_needs_both_travels_and_defaults_to_the_nav_source() -> None:
    move = decode(WheelMove, b'{"left": 0.5, "right": 0.5}')
    assert (move.left, move.right, move.source, move.move_id) == (0.5, 0.5, "nav", None)


@pytest.mark.parametrize(
    ("payload", "why"),
    [
        (b'{"left": 0.5}', "right"),
        (b'{"left": NaN, "right": 0}', "not valid JSON"),
        (b'{"left": 1e999, "right": 0}', "not finite"),
        (b'{"left": "far", "right": 0}', "float"),
        (b'{"left": 0, "right": 0, "source": "a/b"}', "source"),
        (b'{"left": 0, "right": 0, "source": "*"}', "source"),
        (b'{"left": 0, "right": 0, "move_id": "xyz"}', "move_id"),
        (b'{"left": 0, "right": 0, "speed": 1}', "speed"),
    ],
)
def test_a_bad_move_is_refused_with_a_reason(payload: bytes, why: str) -> None:
    with pytest.raises(PayloadError, match=why):
        decode(WheelMove, payload)


def test_the_keys_carry_the_move_and_its_progress() -> None:
    keys = Keys("fleet/a")
    assert keys.wheels_move == "fleet/a/wheels/move" and keys.wheels_position == "fleet/a/wheels/position"
    assert keys.message_for(keys.wheels_move) is WheelMove and keys.message_for(keys.wheels_position) is WheelPosition
    assert WheelMoveReply(False).reason == ""
