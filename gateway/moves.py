"""The robot's own position moves (``<prefix>/wheels/move``), sans I/O: who may start one, what ends it, its progress.

A move is a command like a velocity command: it is its source's, weighed by the arbiter, refused with a sentence while
the e-stop is engaged, the link is down or another source outranks it, and ended by the e-stop (EMG_STOP), by any
velocity command the arbiter lets through, by a lock, or by its own deadline (NORMAL_STOP). The rules are
docs/safety.md "Position moves"; a move's course from the readings is :class:`~blackmetal.gateway.position.Run`'s.
"""

from __future__ import annotations

import math
import secrets
from collections.abc import Callable
from typing import TYPE_CHECKING

from blackmetal import wire
from blackmetal.schemas import MoveState, PayloadError, Twist, WheelMove, WheelMoveReply, WheelPosition, decode, excerpt
from blackmetal.wire import CommandCode

from .arbiter import Why
from .commands import ClientInputs
from .position import MIN_MOVE_GAP_S, POSITION_POLL_HZ, STALL_S, Run, Step, plan_move, travel_refusal
from .safety_states import STILL, Driving

if TYPE_CHECKING:
    from .exchange import Exchange
    from .latch import Latch
    from .links import Links
    from .settings import GatewaySettings

#: A zero Twist: what a move's source is heard to command while its move runs (the wheels' own control moves them).
_STILL_TWIST = Twist()


class MoveInputs(ClientInputs):
    """Position moves on top of the client inputs; :class:`~blackmetal.gateway.core.GatewayCore` sends and reads."""

    if TYPE_CHECKING:  # the robot's side, in GatewayCore
        links: Links
        exchange: Exchange
        stopping: bool

        def _send(self, request: wire.Request, now: float) -> bool: ...
        def _congested(self) -> bool: ...

    def __init__(self, settings: GatewaySettings, now: float, wallclock: Callable[[], float], latch: Latch | None) -> None:
        super().__init__(settings, now, wallclock, latch)
        #: The move under way, if any.
        self.move: Run | None = None
        #: Moves that ended, with why and when: published and reported once the bytes are taken (an EMG_STOP waits for nothing).
        self._ended: list[tuple[Run, str, float]] = []
        #: When the move's source is heard again (its move holds it live in the arbiter, as a stream of commands would).
        self._move_hold_at = math.inf
        #: When the latest move was accepted.
        self._move_accepted_at = -math.inf
        #: Velocity polls between position polls while a move runs.
        self._position_every = 1
        self._polls_to_position = 0

    def on_wheel_move(self, payload: bytes | None, now: float) -> WheelMoveReply:
        """A get on ``<prefix>/wheels/move``: the move starts (its first reading is asked at once), or why not."""
        key = self.keys.wheels_move
        try:
            request = decode(WheelMove, payload or b"")
        except PayloadError as exc:
            reason = f'{exc}; send {{"left": 0.5, "right": 0.5}} (rim travel of each wheel, m) and optionally "source"'
            self.reject(key, reason, now, exc.excerpt)
            return WheelMoveReply(False, reason=reason)
        self._arbitrate(now)  # a source that fell silent hands over before the move is weighed
        refusal = self._move_refusal(request, now)
        if refusal is not None:
            self.reject(key, refusal, now, excerpt(payload or b""))
            return WheelMoveReply(False, request.move_id, refusal)
        s = self.settings
        plan = plan_move(request.left, request.right, s.impulses_left, s.impulses_right, s.position_speed, s.keepalive)
        move_id = request.move_id or secrets.token_hex(16)
        self._move_accepted_at = now
        if self.move is not None:
            self._end_move(f"replaced by move {move_id}", now, CommandCode.SET_LR_WHEEL_VELOCITY)
        previous = self.arbiter.active
        self.arbiter.offer(request.source, _STILL_TWIST, now)
        if self.arbiter.active != previous:
            self._driver_changed(request.source, previous, Why.OUTRANKS)
        self._move_hold_at = now + 0.5 * self.arbiter.timeout_of(request.source)
        self.governor.observe_motion(0.0, 0.0, now)  # the wheels move by the robot's own control now: no stop to confirm
        self.move = Run(move_id, request.source, plan, now)
        self._position_every = max(1, round(s.poll_hz / POSITION_POLL_HZ))
        self._poll_position(now)
        return WheelMoveReply(True, move_id, "", plan.left, plan.right, round(plan.expected, 3), round(plan.deadline_after, 3))

    def _move_refusal(self, request: WheelMove, now: float) -> str | None:
        """Why ``request`` may not start now, if it may not."""
        source, arbiter, governor = request.source, self.arbiter, self.governor
        if not self.settings.position_moves:
            return (
                "position moves are off on this gateway (a robot's support for SET_LR_WHEEL_POSITION is not known): start "
                "it with --position-moves for a robot that supports them (the simulator does)"
            )
        if governor.estop:
            return 'emergency stop is engaged: a position move is refused until {"engaged": false} is put on estop/release'
        if self.stopping:
            return "the gateway is stopping: a position move is refused"
        if not self.links.control.connected or not governor.link_up:
            return "robot control link is down: a position move is refused, not queued"
        if self.conflict.active(now):
            return self.conflict.reason()
        if not arbiter.has_source(source):
            return f"unknown command source {source!r}: the gateway's sources are {', '.join(arbiter.names)} (see --source)"
        priority = arbiter.priority_of(source)
        if priority <= arbiter.lock_priority(now):
            return f"a lock blocks source {source!r} (priority {priority}): its position move is refused"
        active = arbiter.active
        if active is not None and active != source and arbiter.priority_of(active) >= priority:
            return f"{active} (priority {arbiter.priority_of(active)}) drives: a move of {source} (priority {priority}) would be outranked"
        limit = governor.settings.max_wheel_speed
        if self.settings.position_speed > limit:
            return (
                f"the robot runs position moves at {self.settings.position_speed:g} m/s, above the gateway's max_wheel_speed "
                f"{limit:g} m/s: refused"
            )
        state = governor.plan(now, self._congested())[0]
        if isinstance(state, Driving) and (state.target != STILL or state.current != STILL):
            return (
                f"a velocity command of {active or 'a source'} is in force: a position move starts from standstill "
                "(put a zero Twist on its cmd_vel, or let it time out, first)"
            )
        if now - self._move_accepted_at < MIN_MOVE_GAP_S:
            return f"moves come faster than one in {MIN_MOVE_GAP_S:g} s: this one is refused, the one before goes on"
        return travel_refusal(request.left, request.right)

    def _check_move(self, now: float) -> None:
        """End the move under way when what allowed it no longer holds (called on every input and deadline)."""
        move = self.move
        if move is None:
            return
        arbiter = self.arbiter
        if self.governor.estop:
            self._end_move("the e-stop is engaged", now, None)  # EMG_STOP goes out, as for any motion
        elif self.conflict.active(now):
            self._end_move(self.conflict.reason(), now, CommandCode.SET_LR_WHEEL_VELOCITY)
        elif arbiter.active != move.source:
            if arbiter.active is not None:
                why = f"{arbiter.active} (priority {arbiter.priority_of(arbiter.active)}) outranks {move.source}"
            elif arbiter.priority_of(move.source) <= arbiter.lock_priority(now):
                why = f"a lock blocks {move.source}"
            else:
                why = f"{move.source} no longer drives"
            self._end_move(why, now, CommandCode.SET_LR_WHEEL_VELOCITY)
        elif self.settings.position_speed > self.governor.settings.max_wheel_speed:
            self._end_move("max_wheel_speed was set below the robot's position speed", now, CommandCode.SET_LR_WHEEL_VELOCITY)
        elif now >= move.deadline:
            self._end_move(f"not done by its deadline ({move.plan.deadline_after:.1f} s): stopped", now, CommandCode.NORMAL_STOP)

    def _velocity_admitted(self, source: str, now: float) -> None:
        """A velocity command of ``source`` drives: it replaces the move under way (its zero too: the robot stands then)."""
        if self.move is not None:
            self._end_move(f"a velocity command of {source} replaces it", now, CommandCode.SET_LR_WHEEL_VELOCITY)

    def _end_move(self, reason: str, now: float, stop: CommandCode | None) -> None:
        """The move ends short: published, reported, and the robot sent ``stop`` if given: zero velocity (which drops a
        position move on the robot), or zero velocity and NORMAL_STOP (as the gateway's own clean stop)."""
        move = self.move
        if move is None:
            return
        self.move = None
        self._move_hold_at = math.inf
        self._ended.append((move, reason, now))
        if stop is not None:  # zero velocity first: its reply starts the governor's wait for the wheels to stand
            self._send(wire.set_velocity(left=0.0, right=0.0), now)
            self.counters.commands_sent += 1
        if stop is CommandCode.NORMAL_STOP:
            self._send(wire.simple(stop), now)
            self.counters.commands_sent += 1

    def _flush_moves(self) -> None:
        """The moves that ended since the last call: published (``ended``, with the reason) and reported."""
        ended, self._ended = self._ended, []
        for move, reason, now in ended:
            self._publish_move(move, MoveState.ENDED, now, reason)
            self.reporter.report(self.keys.wheels_move, f"move {move.move_id} of {move.source} ended: {reason}", now=now)

    def _move_sent(self, request: wire.Request, now: float) -> None:
        """A motion command other than the move's own goes out: it replaces the move on the robot."""
        if request.command is CommandCode.EMG_STOP:
            self._end_move("the e-stop is engaged", now, None)
        elif self.stopping:
            self._end_move("the gateway is stopping", now, None)
        else:
            name = "NORMAL_STOP" if request.command is CommandCode.NORMAL_STOP else "a velocity command"
            self._end_move(f"{name} sent to the robot", now, None)

    def _move_tick(self, now: float) -> None:
        """The move's own deadlines: its source heard again, its time limit."""
        move = self.move
        if move is None:
            return
        if now >= self._move_hold_at:
            self._move_hold_at = now + 0.5 * self.arbiter.timeout_of(move.source)
            if self.arbiter.active == move.source:
                self.arbiter.offer(move.source, _STILL_TWIST, now)
        self._check_move(now)

    def _move_deadline(self) -> float:
        move = self.move
        return math.inf if move is None else min(move.deadline, self._move_hold_at)

    def _poll_position(self, now: float) -> None:
        """Ask for the wheels' positions, one request at a time, when motion may go out."""
        move = self.move
        if move is None or self._congested():
            return
        if any(p.request.command is CommandCode.GET_LR_WHEEL_POSITION for p in self.exchange.outstanding):
            return
        if self._send(wire.simple(CommandCode.GET_LR_WHEEL_POSITION), now):
            move.poll_sent()
            self._polls_to_position = self._position_every

    def _after_velocity_poll(self, now: float) -> None:
        """A velocity poll went out: every ``_position_every``-th is followed by a position poll while a move runs."""
        if self.move is None:
            return
        self._polls_to_position -= 1
        if self._polls_to_position <= 0:
            self._poll_position(now)

    def _on_position(self, reading: wire.PositionReading | None, now: float) -> None:
        """A position reading (None: lost); the move goes on, sends its next segment, or ends."""
        move = self.move
        if move is None:
            return
        if reading is None:
            move.poll_lost()
            return
        if self._ended:  # a move ended before this one began: its end is told first
            self._flush_moves()
        step = move.on_reading(reading.left, reading.right, now)
        if step is Step.SEND:
            left, right = move.command
            if self._congested() or not self._send(wire.Request(CommandCode.SET_LR_WHEEL_POSITION, left=left, right=right), now):
                move.defer()  # sent from the next reading
                return
            self.counters.commands_sent += 1
            move.command_sent(now)
            self._poll_position(now)  # where it got to: asked at once after the command (the robot answers in order)
        elif step is Step.DONE:
            self.move = None
            self._move_hold_at = math.inf
            self._publish_move(move, MoveState.DONE, now)
            return
        elif step is Step.STALLED:
            self._end_move(f"the wheels stopped short of the target for {STALL_S:g} s: stopped", now, CommandCode.NORMAL_STOP)
            return
        self._publish_move(move, MoveState.RUNNING, now)

    def _position_not_taken(self, request: wire.Request, lost: bool, now: float) -> None:
        """The robot did not take a segment (FULL_BUFFER: sent again from the next reading) or did not answer (ended)."""
        move = self.move
        if move is None or request.command is not CommandCode.SET_LR_WHEEL_POSITION:
            return
        if lost:
            self._end_move("the robot did not answer the position command: stopped", now, CommandCode.NORMAL_STOP)
        elif not move.dropped():
            self._end_move(f"the robot did not take the position command {move.resends} times: stopped", now, CommandCode.NORMAL_STOP)

    def _publish_move(self, move: Run, state: MoveState, now: float, reason: str = "") -> None:
        start = move.start
        if start is None or move.reading is None:
            start = reading = (0, 0)  # ended before its first reading: nothing read
            target = (0, 0)
        else:
            reading = move.reading
            target = move.target()
        self._events.append(
            WheelPosition(
                stamp=self.wallclock(),
                move_id=move.move_id,
                source=move.source,
                state=state,
                left=reading[0],
                right=reading[1],
                start_left=start[0],
                start_right=start[1],
                target_left=target[0],
                target_right=target[1],
                elapsed=round(now - move.accepted_at, 6),
                reason=reason,
            )
        )
