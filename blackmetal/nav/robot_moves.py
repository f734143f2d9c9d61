"""A relative move (``nav/move``) run by the robot's own position control, the navigation's side, sans I/O.

Where the gateway's parameters say the robot runs position moves (``position_moves``), a :class:`NavMove` may go to
the gateway as a :class:`WheelMove` on ``<prefix>/wheels/move`` instead of through the pose controller: a distance is
the same rim travel on both wheels, an angle opposite travels of ``angle * wheel_separation / 2``. The gateway
publishes the wheels' cumulative impulses on ``<prefix>/wheels/position``; :class:`RobotMoveTracker` turns them into
what the navigation's feedback says (distance or angle left, time left) and tells done, ended and stalled apart.
The gateway's rules: docs/safety.md "Position moves".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from blackmetal import robot_model as model
from blackmetal.schemas import GatewayParams, GoalState, MoveState, NavMove, WheelMove, WheelMoveReply, WheelPosition

#: Wheels that have not turned (or a gateway that has not said where they are) for this long have stopped (s); a
#: little longer than the gateway's own stall time, so that its word (``ended``, with the reason) comes first.
STALL_S = 1.5
#: A wheel within this many impulses of its target is there (as the gateway counts it).
TOLERANCE_IMPULSES = 3
#: Reported right impulses are the natural ones times this (the right encoder is mirrored).
_MIRROR = -1 if model.RIGHT_ENCODER_MIRRORED else 1


@dataclass(frozen=True, slots=True)
class RobotConstants:
    """What the navigation needs of the robot to move it by its own position control: whether it may, at what rim
    speed, and its geometry and encoders (the gateway's, from its parameter table)."""

    position_moves: bool = False
    position_speed: float = 0.3
    wheel_separation: float = model.WHEEL_SEPARATION
    impulses_left: float = model.IMPULSES_PER_METER_LEFT
    impulses_right: float = model.IMPULSES_PER_METER_RIGHT

    @classmethod
    def of(cls, params: GatewayParams) -> RobotConstants:
        """The constants in the gateway's parameters (``<prefix>/gateway/params``); a gateway that names no
        ``position_moves`` has none (older gateways), and what it does not name keeps its nominal value."""
        values = {p.name: p.value for p in params.params}
        kept: dict[str, bool | float] = {}
        for name, kind in (
            ("position_moves", bool),
            ("position_speed", float),
            ("wheel_separation", float),
            ("impulses_left", float),
            ("impulses_right", float),
        ):
            value = values.get(name)
            if kind is bool and isinstance(value, bool):
                kept[name] = value
            elif kind is float and isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0:
                kept[name] = float(value)
        return cls(**kept)  # type: ignore[arg-type]


def wheel_travels(move: NavMove, constants: RobotConstants) -> tuple[float, float]:
    """Rim travel of the left and right wheel (m, forward positive) that carries out ``move``."""
    if move.angle:
        half = move.angle * constants.wheel_separation / 2.0
        return -half, half
    return move.distance, move.distance


def wheel_move(move: NavMove, constants: RobotConstants, move_id: str | None = None, source: str = "nav") -> WheelMove:
    """The request to put on ``<prefix>/wheels/move`` for ``move`` (``move_id``: the goal's id, so both name it alike)."""
    left, right = wheel_travels(move, constants)
    return WheelMove(left=left, right=right, source=source, move_id=move_id)


def expected_duration(move: NavMove, constants: RobotConstants) -> float:
    """Seconds the robot takes for ``move`` at its position speed (the gateway's own figure is in its reply)."""
    left, right = wheel_travels(move, constants)
    return max(abs(left), abs(right)) / constants.position_speed


@dataclass(frozen=True, slots=True)
class MoveProgress:
    """Where a robot move is: ``remaining`` (m for a distance, rad for an angle, signed as the move), the share done,
    the time left at the position speed, and whether it is over (``done``: at the target; ``ended``: short of it,
    ``reason`` says why; ``stalled``: the wheels, or the gateway's word of them, stopped short)."""

    remaining: float
    fraction: float
    eta: float
    done: bool = False
    ended: bool = False
    stalled: bool = False
    reason: str = ""

    @property
    def over(self) -> bool:
        return self.done or self.ended or self.stalled


class RobotMoveTracker:
    """One robot move seen from the navigation: fed the gateway's reply and its ``wheels/position`` publications."""

    def __init__(self, move: NavMove, constants: RobotConstants, now: float, stall_s: float = STALL_S) -> None:
        self.move = move
        self.constants = constants
        self.stall_s = stall_s
        self.move_id: str | None = None
        self.started_at = now
        self.last_change = now
        self.reading: tuple[int, int] | None = None
        #: The last reading was at the target (a lost ``done`` publication is made good by the wheels standing there).
        self.there = False
        self.progress = MoveProgress(self._total(), 0.0, expected_duration(move, constants))

    def on_reply(self, reply: WheelMoveReply, now: float) -> str | None:
        """The gateway's answer: None when the move runs (its id is kept), else why it was refused."""
        if not reply.accepted:
            self.progress = MoveProgress(self._total(), 0.0, 0.0, ended=True, reason=reply.reason)
            return reply.reason or "the gateway refused the move"
        self.move_id = reply.move_id
        self.started_at = self.last_change = now
        return None

    def on_position(self, position: WheelPosition, now: float) -> MoveProgress | None:
        """A publication on ``wheels/position``: the progress it shows, or None when it is another move's."""
        if self.move_id is None or position.move_id != self.move_id:
            return None
        reading = (position.left, position.right)
        if reading != self.reading:
            self.reading, self.last_change = reading, now
        c = self.constants
        # travel so far of each wheel, m, natural sign (the right encoder counts backwards forward)
        left = (position.left - position.start_left) / c.impulses_left
        right = _MIRROR * (position.right - position.start_right) / c.impulses_right
        to_left = (position.target_left - position.left) / c.impulses_left
        to_right = _MIRROR * (position.target_right - position.right) / c.impulses_right
        if self.move.angle:
            remaining = self.move.angle - (right - left) / c.wheel_separation
        else:
            remaining = self.move.distance - (left + right) / 2.0
        total = self._total()
        fraction = 1.0 if total == 0 else min(1.0, max(0.0, 1.0 - remaining / total))
        eta = max(abs(to_left), abs(to_right)) / c.position_speed
        there = (
            abs(position.target_left - position.left) <= TOLERANCE_IMPULSES
            and abs(position.target_right - position.right) <= TOLERANCE_IMPULSES
        )
        self.there = there
        if position.state is MoveState.DONE:
            self.progress = MoveProgress(remaining, 1.0 if there else fraction, 0.0, done=True)
        elif position.state is MoveState.ENDED:
            self.progress = MoveProgress(remaining, fraction, 0.0, ended=True, reason=position.reason or "the gateway ended the move")
        else:
            self.progress = MoveProgress(remaining, fraction, eta)
        return self.progress

    def check(self, now: float) -> MoveProgress:
        """The progress at ``now``: after ``stall_s`` without the wheels turning (or the gateway's word of them), done
        when they stand at the target, stalled short of it."""
        progress = self.progress
        if not progress.over and now - self.last_change >= self.stall_s:
            if self.there:
                self.progress = progress = MoveProgress(progress.remaining, 1.0, 0.0, done=True)
                return progress
            reason = (
                "the gateway said nothing of the move"
                if self.reading is None
                else f"the wheels stood still for {self.stall_s:g} s short of the target"
            )
            self.progress = progress = MoveProgress(progress.remaining, progress.fraction, 0.0, stalled=True, reason=reason)
        return progress

    def deadline(self) -> float:
        """When :meth:`check` may next find the move stalled (inf: it is over)."""
        return math.inf if self.progress.over else self.last_change + self.stall_s

    def _total(self) -> float:
        return self.move.angle or self.move.distance


def outcome(progress: MoveProgress) -> tuple[GoalState, str] | None:
    """How the goal of a robot move ends for ``progress`` (None: it runs): succeeded at the target, else aborted with
    the reason (a cancel of the navigation's own is the navigation's to call canceled)."""
    if progress.done:
        return GoalState.SUCCEEDED, ""
    if progress.ended or progress.stalled:
        return GoalState.ABORTED, f"the robot's position move ended: {progress.reason}"
    return None
