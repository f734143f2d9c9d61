"""One position move of the robot's own (SET_LR_WHEEL_POSITION), sans I/O: its plan, and its course from the readings.

A move's travels become whole impulses per wheel with the gateway's calibrated encoders. It is cut into segments that
each take at most ``segment_s`` (the keep-alive, well inside the robot's 10 s watchdog): each segment goes out as the
travel from the wheels' reading, taken while they stand, to the segment's end, so a segment the robot fell short of
or overshot is made good by the next, and a command the robot dropped is sent again from where the wheels stand.
The rules the gateway keeps around a move (who may start one, what ends it): docs/safety.md "Position moves".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from blackmetal.robot_model import RIGHT_ENCODER_MIRRORED

#: A wheel within this many impulses of its target is there (the robot's own control ends within one or two).
TOLERANCE_IMPULSES = 3
#: Wheels that have not turned for this long short of their target have stopped: the move ends (s).
STALL_S = 1.0
#: Longest rim travel of one move (m): a longer one is a client's mistake, not a move (it takes 83 s at 0.3 m/s).
MAX_TRAVEL_M = 25.0
#: A move is stopped (NORMAL_STOP) after its expected time at the position speed times this, plus DEADLINE_MARGIN_S.
DEADLINE_FACTOR = 1.5
DEADLINE_MARGIN_S = 1.0
#: A segment the robot drops (FULL_BUFFER) is sent again this many times at most.
MAX_RESENDS = 5
#: At most one move is accepted in this long (s): a flood of moves would only send the robot stops and readings.
MIN_MOVE_GAP_S = 0.1
#: Position readings per second while a move runs (at most one for every velocity poll).
POSITION_POLL_HZ = 25.0
#: Reported right impulses are the natural ones times this.
_MIRROR = -1 if RIGHT_ENCODER_MIRRORED else 1


@dataclass(frozen=True, slots=True)
class MovePlan:
    """A move in impulses (natural sign: forward positive on both wheels), its segments and its time limits (s)."""

    left: int
    right: int
    segments: int
    expected: float
    deadline_after: float


def plan_move(left_m: float, right_m: float, impulses_left: float, impulses_right: float, speed: float, segment_s: float) -> MovePlan:
    """The plan of a move of ``left_m``/``right_m`` metres at the robot's ``speed`` (m/s), segments of at most ``segment_s``."""
    left, right = round(left_m * impulses_left), round(right_m * impulses_right)
    expected = max(abs(left) / impulses_left, abs(right) / impulses_right) / speed
    segments = max(1, math.ceil(expected / segment_s - 1e-9))
    return MovePlan(left, right, segments, expected, expected * DEADLINE_FACTOR + DEADLINE_MARGIN_S)


def travel_refusal(left_m: float, right_m: float) -> str | None:
    """Why a move of these rim travels is refused, if it is (non-finite travels never reach here: the schema refuses them)."""
    longest = max(abs(left_m), abs(right_m))
    if longest > MAX_TRAVEL_M:
        return f"a wheel travel of {longest:g} m is beyond the {MAX_TRAVEL_M:g} m a position move may take: send shorter moves"
    return None


class Step(Enum):
    """What a reading asks of the gateway."""

    NOTHING = "nothing"
    SEND = "send"  # the segment's command (Run.command) goes out now
    DONE = "done"
    STALLED = "stalled"


class Run:
    """A move under way: fed position readings (as the robot reports them) in the order their requests went out."""

    def __init__(self, move_id: str, source: str, plan: MovePlan, accepted_at: float) -> None:
        self.move_id = move_id
        self.source = source
        self.plan = plan
        self.accepted_at = accepted_at
        self.deadline = accepted_at + plan.deadline_after
        self.start: tuple[int, int] | None = None
        self.reading: tuple[int, int] | None = None
        #: The segment under way (1..segments), and whether its command is still to go out at the next fresh reading.
        self.segment = 1
        self.want_send = True
        #: The command to send (natural-sign impulses), set when a reading returns Step.SEND.
        self.command = (0, 0)
        #: Position requests sent, and readings taken (or lost): a reading is fresh when it was asked after ``fresh_after``.
        self.polls_sent = 0
        self.readings = 0
        self.fresh_after = 0
        self.last_change = accepted_at
        self.resends = 0

    def target(self, segment: int | None = None) -> tuple[int, int]:
        """Where segment ``segment`` (default: the last) ends, as the robot reports positions."""
        plan, start = self.plan, self.start
        assert start is not None
        share = (self.plan.segments if segment is None else segment) / plan.segments
        return start[0] + round(plan.left * share), start[1] + _MIRROR * round(plan.right * share)

    def poll_sent(self) -> None:
        self.polls_sent += 1

    def poll_lost(self) -> None:
        self.readings += 1

    def command_sent(self, now: float) -> None:
        """The segment's command went out: only readings asked after it tell where it got to (and a stall counts from now)."""
        self.want_send = False
        self.fresh_after = self.polls_sent
        self.last_change = now

    def defer(self) -> None:
        """The segment's command could not go out now (the robot is behind on its replies): from the next reading."""
        self.want_send = True
        self.fresh_after = self.polls_sent

    def dropped(self) -> bool:
        """The robot did not take the segment's command (FULL_BUFFER): sent again from the next reading; False when
        it was dropped MAX_RESENDS times already."""
        self.resends += 1
        self.want_send = True
        self.fresh_after = self.polls_sent
        return self.resends <= MAX_RESENDS

    def on_reading(self, left: int, right: int, now: float) -> Step:
        """A position reading; what the gateway does next because of it."""
        self.readings += 1
        reading, previous = (left, right), self.reading
        self.reading = reading
        if reading != previous:
            self.last_change = now
        if self.readings <= self.fresh_after:
            return Step.NOTHING  # asked before the latest command went out
        if self.start is None:
            self.start = reading
        target = self.target(self.segment)
        if self.want_send:
            return self._send_from(reading)
        there = abs(left - target[0]) <= TOLERANCE_IMPULSES and abs(right - target[1]) <= TOLERANCE_IMPULSES
        if there and reading == previous:
            if self.segment == self.plan.segments:
                return Step.DONE
            self.segment += 1
            return self._send_from(reading)
        if not there and now - self.last_change >= STALL_S:
            return Step.STALLED
        return Step.NOTHING

    def _send_from(self, reading: tuple[int, int]) -> Step:
        """The current segment's command from ``reading``, or the next segment's when there is nothing left to this one."""
        while True:
            target = self.target(self.segment)
            command = (target[0] - reading[0], _MIRROR * (target[1] - reading[1]))
            if command != (0, 0):
                self.command = command
                return Step.SEND
            if self.segment == self.plan.segments:
                return Step.DONE
            self.segment += 1

    def remaining(self) -> tuple[int, int]:
        """Impulses each wheel still has to go to the move's end (natural sign; the whole move before the first reading)."""
        if self.start is None or self.reading is None:
            return self.plan.left, self.plan.right
        target = self.target()
        return target[0] - self.reading[0], _MIRROR * (target[1] - self.reading[1])
