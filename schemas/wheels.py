"""Messages of the robot's own position moves (``<prefix>/wheels/move``, ``<prefix>/wheels/position``).

A position move is the robot's SET_LR_WHEEL_POSITION: each wheel turns a relative travel at the robot's own rim speed,
read back with GET_LR_WHEEL_POSITION. The gateway carries one out only where its settings say the robot supports it
(``position_moves``); the rules are docs/safety.md "Position moves". Travels are metres of rim, forward positive.
"""

from __future__ import annotations

import math
from enum import StrEnum
from typing import Annotated

import msgspec

from .messages import Finite

#: A move id: 32 lower-case hex digits (as a navigation goal id, so a goal and its move may share one).
MoveId = Annotated[str, msgspec.Meta(pattern="^[0-9a-f]{32}$", description="32 lower-case hex digits")]
#: A command source's name: one key chunk (``nav``, ``default``, ...).
SourceName = Annotated[str, msgspec.Meta(min_length=1, max_length=64, pattern="^[^*$?#/ @][^*$?#/ ]*$")]


class WheelMove(msgspec.Struct, forbid_unknown_fields=True):
    """Payload of a get on ``<prefix>/wheels/move``: turn the left and right wheels by these rim travels (m), relative
    to where they stand, with the robot's own position control, as command source ``source``."""

    left: Finite
    right: Finite
    source: SourceName = "nav"
    move_id: MoveId | None = None

    def __post_init__(self) -> None:
        for name, value in (("left", self.left), ("right", self.right)):
            if not math.isfinite(value):
                raise ValueError(f"move.{name} must be a finite number, got {value!r}")


class WheelMoveReply(msgspec.Struct):
    """The answer to a move: accepted with its id, the impulses asked of each wheel (natural sign) and its time
    limits, or refused with a sentence that says why."""

    accepted: bool
    move_id: str | None = None
    reason: str = ""
    left_impulses: int = 0
    right_impulses: int = 0
    #: Seconds the move takes at the robot's position speed, and after which the gateway stops it (NORMAL_STOP).
    expected: Finite = 0.0
    deadline: Finite = 0.0


class MoveState(StrEnum):
    """Where a position move is: running, done (the wheels stand at their target), or ended short (``reason`` says why)."""

    RUNNING = "running"
    DONE = "done"
    ENDED = "ended"


class WheelPosition(msgspec.Struct):
    """Published on ``<prefix>/wheels/position`` at each reading while a position move runs, and once when it ends.

    ``left``/``right`` and the ``start_*``/``target_*`` values are cumulative impulses exactly as the robot reports
    them (GET_LR_WHEEL_POSITION: the right encoder mirrored, negative forward). ``stamp`` is Unix time, ``elapsed`` the
    seconds since the move was accepted.
    """

    stamp: Finite
    move_id: str
    source: str
    state: MoveState
    left: int
    right: int
    start_left: int
    start_right: int
    target_left: int
    target_right: int
    elapsed: Finite
    reason: str = ""


#: The position-move messages, by the name used for its JSON Schema file.
WHEEL_MESSAGE_TYPES: dict[str, type[msgspec.Struct]] = {
    "WheelMove": WheelMove,
    "WheelMoveReply": WheelMoveReply,
    "WheelPosition": WheelPosition,
}
