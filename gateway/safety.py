"""What velocity the robot gets, and when: limits, timeout, e-stop, dedup, keep-alive, confirmed stops (docs/safety.md).

One :data:`State`, replaced by every input; what it does next, and from when, is one decision
(:meth:`Governor.plan`) that ``next_command`` and ``next_deadline`` both read, so they cannot disagree. A state
not ramping does not change before its deadline, so a look then is answered from the decision kept for it; the
ramp's clock (``current_at``) moves only while the twist changes, so a ramp never steps further than its limit
allows for the time it ran.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import NamedTuple

from blackmetal.robot_model import STANDSTILL, WheelSpeeds, twist_to_wheels
from blackmetal.schemas import Twist

from .safety_states import (
    NOTHING_DUE,
    RAMP_STEP_S,
    RETRY_CAP_S,
    STANDING_SPEED,
    STILL,
    STOP_GRACE_S,
    CommandReason,
    Driving,
    Due,
    EStopped,
    Offline,
    Robot,
    SafetySettings,
    Sent,
    State,
    Velocity,
    VelocityCommand,
    retry_delay,
)


class _Planned(NamedTuple):
    """The decision made for one state object at one look (:meth:`Governor.plan`): a command costs one, not three."""

    of: State
    now: float
    congested: bool
    settings: SafetySettings
    state: State
    due: Due


class _Deadline(NamedTuple):
    """The decision taken at -inf for one state object; ``settled`` (not ramping): it holds at any look before its deadline."""

    of: State
    congested: bool
    settings: SafetySettings
    due: Due
    settled: bool


class _WheelsOf(NamedTuple):
    twist: Velocity
    settings: SafetySettings
    wheels: WheelSpeeds


class Governor:
    def __init__(self, settings: SafetySettings) -> None:
        self.settings = settings
        self.state: State = Offline()
        self._planned: _Planned | None = None
        self._deadline: _Deadline | None = None
        self._wheels_of: _WheelsOf | None = None

    @property
    def estop(self) -> bool:
        """The e-stop is latched (with or without a link)."""
        state = self.state
        return isinstance(state, EStopped) or (isinstance(state, Offline) and state.estop)

    @property
    def link_up(self) -> bool:
        return not isinstance(self.state, Offline)

    @property
    def accepted(self) -> WheelSpeeds | None:
        """The wheel speeds the robot last accepted on this link (None: nothing yet)."""
        return None if isinstance(self.state, Offline) else self.state.robot.accepted

    @property
    def last_cmd_at(self) -> float:
        """When the last valid cmd_vel was heard (-inf: none since the link came up, a release or a brake)."""
        return -math.inf if isinstance(self.state, Offline) else self.state.heard_at

    def timed_out(self, now: float) -> bool:
        timeout = self.settings.cmd_timeout
        return timeout > 0 and now >= self.last_cmd_at + timeout

    def refusal(self, twist: Twist) -> str | None:
        """Why a velocity command would be refused now, if it would (:meth:`on_twist` refuses it then)."""
        if self.estop:
            return 'emergency stop is engaged: cmd_vel refused until {"engaged": false} is put on estop/release'
        if not self.link_up:
            return "robot control link is down: cmd_vel refused, not queued"
        v, w = twist.linear.x, twist.angular.z
        s = self.settings
        if abs(v) > s.plausible_linear:
            return f"linear.x {v!r} m/s is beyond any plausible command (|v| <= {s.plausible_linear})"
        if abs(w) > s.plausible_angular:
            return f"angular.z {w!r} rad/s is beyond any plausible command (|w| <= {s.plausible_angular})"
        return None

    def on_twist(self, twist: Twist, heard_at: float, now: float | None = None) -> str | None:
        """Take a velocity command heard at ``heard_at``, or return why it is refused; one handed over from a source's past
        ramps from ``now``, its command timeout runs from ``heard_at``."""
        reason = self.refusal(twist)
        if reason is None:
            self.steer(twist, heard_at, heard_at if now is None else now)
        return reason

    def steer(self, twist: Twist, heard_at: float, now: float) -> None:
        """:meth:`on_twist` for a command its caller found not refused by :meth:`refusal` in this same state."""
        if isinstance(self.state, Driving):
            state = self._ramp_now(self.state, now)
            self.state = Driving(state.robot, (twist.linear.x, twist.angular.z), heard_at, state.current, state.current_at)

    def on_estop(self, engaged: bool, now: float) -> None:
        """Latch (EMG_STOP at once; again on every new link) or release (a fresh cmd_vel is then needed to move again)."""
        state = self.state
        if isinstance(state, Offline):
            self.state = Offline(estop=engaged)
        elif engaged:
            # EMG_STOP stops the wheels: as far as velocity goes, standstill was sent and nothing is to be re-sent
            sent = state.robot.sent
            standstill = Sent(STANDSTILL, -math.inf) if sent is None else Sent(STANDSTILL, sent.at, sent.resends)
            robot = state.robot
            robot = Robot(standstill, robot.accepted, robot.accepted_at, robot.moving)  # constructors: the EMG_STOP's path
            if isinstance(state, Driving):
                self.state = EStopped(robot, emg_at=now, heard_at=state.heard_at)
            else:
                self.state = _with_robot(state, robot)
        elif isinstance(state, EStopped):
            self.state = Driving(state.robot, current_at=now)
        else:
            self.state = replace(self._ramp_now(state, now), heard_at=-math.inf)  # a release while driving also wants a fresh cmd_vel

    def brake(self, now: float) -> None:
        """Stop now, whatever was commanded (a conflict, a lock); a fresh cmd_vel is needed to move again."""
        if isinstance(self.state, Driving):
            self.state = replace(self._ramp_now(self.state, now), target=STILL, heard_at=-math.inf)
        elif isinstance(self.state, EStopped):
            self.state = replace(self.state, heard_at=-math.inf)

    def on_link_up(self, now: float) -> None:
        """A new connection: the robot gets zero velocity (and EMG_STOP if latched), never an old motion."""
        self.state = EStopped(Robot(), emg_at=now) if self.estop else Driving(Robot(), current_at=now)

    def on_link_down(self) -> None:
        """The link closed: nothing is sent until the next one; a latched e-stop stays latched."""
        self.state = Offline(estop=self.estop)

    def on_accepted(self, wheels: WheelSpeeds, now: float) -> None:
        """The robot answered RECIEVE_OK to a velocity command."""
        if isinstance(self.state, Offline):
            return
        robot = self.state.robot
        sent = robot.sent
        if sent is not None and wheels == sent.wheels and (sent.resends or sent.resend_at is not None):
            sent = Sent(sent.wheels, sent.at)
        self.state = _with_robot(self.state, Robot(sent, wheels, now, robot.moving))

    def on_dropped(self, wheels: WheelSpeeds, now: float) -> str | None:
        """The robot did not take ``wheels`` (FULL_BUFFER, or no reply). Returns a reason to report, if any."""
        if isinstance(self.state, Offline):
            return None
        robot = self.state.robot
        sent = robot.sent
        if sent is None or wheels != sent.wheels or sent.resend_at is not None:
            return None  # superseded by a newer command, or a re-send is already planned
        if not wheels.is_zero and sent.resends >= self.settings.full_buffer_retries:
            return f"robot did not take the velocity command {sent.resends + 1} times: given up until the command changes"
        resends = sent.resends + 1
        sent = replace(sent, resends=resends, resend_at=now + retry_delay(resends))
        self.state = replace(self.state, robot=replace(robot, sent=sent))
        return None

    def on_emg_stop_dropped(self, now: float) -> None:
        """EMG_STOP was not taken: send it again after a growing pause, for as long as the stop is engaged."""
        if isinstance(self.state, EStopped):
            self.state = self.state.emg_again(now)

    def on_emg_stop_sent(self) -> None:
        if isinstance(self.state, EStopped):
            state = self.state
            self.state = EStopped(state.robot, state.emg_at, False, state.emg_resends, state.heard_at)

    def observe_motion(self, left: float, right: float, now: float) -> None:
        """The wheels' rim speeds as polled (m/s)."""
        if not isinstance(self.state, Offline):
            moving = max(abs(left), abs(right)) > STANDING_SPEED
            robot = self.state.robot
            if moving != robot.moving:  # most polls change nothing: the state, and what was decided of it, stay
                self.state = _with_robot(self.state, Robot(robot.sent, robot.accepted, robot.accepted_at, moving))

    def plan(self, now: float, congested: bool = False) -> tuple[State, Due]:
        """The one decision: the state brought up to ``now``, and what it does next, from when; nothing is committed.
        ``congested``: the robot is behind on its replies; motion waits (the next reply calls again), a stop never does."""
        state = self.state
        kept = self._deadline
        if (
            kept is not None
            and kept.settled
            and kept.of is state
            and now < kept.due.at
            and kept.congested == congested
            and kept.settings is self.settings
        ):
            return state, kept.due  # time changes nothing before the deadline: the decision kept for this state holds
        planned = self._planned
        if (
            planned is not None
            and planned.of is self.state
            and planned.now == now
            and planned.congested == congested
            and planned.settings is self.settings
        ):
            return planned.state, planned.due
        state = self._advance(self.state, now)
        due = self._due(state, now, congested)
        self._planned = _Planned(self.state, now, congested, self.settings, state, due)
        return state, due

    def next_command(self, now: float, congested: bool = False) -> VelocityCommand | None:
        """The velocity to send now, if any; call on every event and every deadline (after EMG_STOP, see :meth:`emg_stop_due`)."""
        state, due = self.plan(now, congested)
        command = due.command if due.at <= now else None
        if command is not None and not isinstance(state, Offline):
            robot = state.robot
            state = _with_robot(state, Robot(_sending(robot.sent, command, now), robot.accepted, robot.accepted_at, robot.moving))
        self.state = state
        return command

    def emg_stop_due(self, now: float) -> bool:
        """True when an EMG_STOP should go out now (before any velocity command); :meth:`on_emg_stop_sent` once it did."""
        if not isinstance(self.state, EStopped):
            return False
        due = self.plan(now)[1]
        return due.emg_stop and due.at <= now

    def next_deadline(self, congested: bool = False) -> float:
        """When :meth:`next_command` or :meth:`emg_stop_due` may next have something to do without a new input
        (the decision taken at -inf: a time not after the last input's means at once)."""
        state = self.state
        kept = self._deadline
        if kept is not None and kept.of is state and kept.congested == congested and kept.settings is self.settings:
            return kept.due.at
        due = self._due(state, -math.inf, congested)
        # not ramping: before due.at time changes nothing, and a look's time only ranks re-sends already due
        settled = not isinstance(state, Driving) or state.current == state.target
        self._deadline = _Deadline(state, congested, self.settings, due, settled)
        return due.at

    def _advance(self, state: State, now: float) -> State:
        """What time alone changes by ``now``: the brake on the command timeout, the ramp, EMG_STOP asked again."""
        if isinstance(state, EStopped) and now >= state.recheck_at:
            return state.emg_again(now)  # EMG_STOP was taken but the wheels still turn
        if not isinstance(state, Driving):
            return state
        target, current, current_at = state.target, state.current, state.current_at
        brake_at = self._brake_at(state)
        if now >= brake_at:
            if brake_at > current_at:  # the commanded twist held until the brake struck; the ramp down runs from then
                current, current_at = self._ramp(current, target, brake_at - current_at), brake_at
            target = STILL
        if current != target:  # still ramping: the ramp's clock moves with it
            current, current_at = self._ramp(current, target, max(0.0, now - current_at)), max(current_at, now)
        if target == state.target and current == state.current and current_at == state.current_at:
            return state  # nothing changed: the same object, so what was decided of it still holds
        return Driving(state.robot, target, state.heard_at, current, current_at)

    def _ramp(self, current: Velocity, target: Velocity, dt: float) -> Velocity:
        """``current`` after ``dt`` seconds toward ``target`` within the acceleration limits."""
        s = self.settings
        return (
            _approach(current[0], target[0], None if s.linear_accel is None else s.linear_accel * dt),
            _approach(current[1], target[1], None if s.angular_accel is None else s.angular_accel * dt),
        )

    def _ramp_now(self, state: Driving, now: float) -> Driving:
        """``state`` brought up to ``now`` with its ramp's clock at ``now``: what an input that changes the target starts from."""
        advanced = self._advance(state, now)
        assert isinstance(advanced, Driving)
        if advanced.current_at >= now:
            return advanced
        return Driving(advanced.robot, advanced.target, advanced.heard_at, advanced.current, now)

    def _due(self, state: State, now: float, congested: bool) -> Due:
        """What ``state`` does next and from when; ``now`` only ranks several re-sends that are all due."""
        if isinstance(state, Offline):
            return NOTHING_DUE
        if isinstance(state, EStopped):
            return Due(state.emg_at, emg_stop=True) if state.emg_pending else Due(state.recheck_at)
        wheels = self._wheels(state.current).wheels
        # a ramp is stepped at least every RAMP_STEP_S; congested, only on its way to a stop (motion waits anyway)
        ramping = state.current != state.target and (not congested or state.target == STILL)
        send = self._send(state, wheels, now, congested)
        look = min(self._brake_at(state), state.current_at + RAMP_STEP_S if ramping else math.inf)
        return send if send.at <= look else Due(look)  # a send and a look at the same time is a send

    def _send(self, state: Driving, wheels: WheelSpeeds, now: float, congested: bool) -> Due:
        """The velocity command a driving state sends next, and from when."""
        if congested and not wheels.is_zero:
            return NOTHING_DUE  # motion waits for the robot's replies, which call again
        s = self.settings
        sent = state.robot.sent
        if sent is None or wheels != sent.wheels:  # coalesced: the latest wanted command goes out once the rate cap allows
            return Due(-math.inf if sent is None else sent.at + 1.0 / s.max_command_hz, VelocityCommand(wheels, CommandReason.NEW))
        # a re-send (or a stop asked for again) first, then the keep-alive: the first already due, else the earliest
        first: Due | None = None
        if sent.resend_at is not None:
            first = Due(sent.resend_at, VelocityCommand(wheels, CommandReason.RETRY))
        elif wheels.is_zero and state.robot.moving and state.robot.accepted is not None and state.robot.accepted.is_zero:
            # the robot accepted a stop but its wheels still turn: give them time to come to rest, then ask again
            at = max(state.robot.accepted_at + STOP_GRACE_S, sent.at + RETRY_CAP_S)
            first = Due(at, VelocityCommand(wheels, CommandReason.STOP_AGAIN))
        if wheels.is_zero:
            return NOTHING_DUE if first is None else first
        keepalive_at = sent.at + s.keepalive
        if first is not None and (first.at <= now or first.at <= keepalive_at):
            return first
        return Due(keepalive_at, VelocityCommand(wheels, CommandReason.KEEPALIVE))

    def _brake_at(self, state: Driving) -> float:
        """When the command timeout brakes (inf: standing still, or no timeout)."""
        timeout = self.settings.cmd_timeout
        return state.heard_at + timeout if timeout > 0 and state.target != STILL else math.inf

    def _wheels(self, twist: Velocity) -> _WheelsOf:
        """The wheel speeds the robot is asked for to drive ``twist``, as the wire carries them."""
        s = self.settings
        kept = self._wheels_of
        if kept is not None and kept.twist == twist and kept.settings is s:
            return kept
        wheels = twist_to_wheels(*twist, s.wheel_separation, s.max_wheel_speed)[0]
        if not s.wheel_gain.is_unity:
            wheels = wheels.scaled(s.wheel_gain)
        kept = self._wheels_of = _WheelsOf(twist, s, wheels.rounded())
        return kept


def _sending(sent: Sent | None, command: VelocityCommand, now: float) -> Sent:
    """What was sent, once ``command`` is: a new command starts afresh; a repeat keeps its count of re-sends."""
    if command.reason is CommandReason.NEW or sent is None:
        return Sent(command.wheels, now)
    return Sent(sent.wheels, now, sent.resends, None if command.reason is CommandReason.RETRY else sent.resend_at)


def _with_robot(state: EStopped | Driving, robot: Robot) -> EStopped | Driving:
    """``state`` with ``robot``: a constructor call, several times cheaper than ``dataclasses.replace``, for every command."""
    if isinstance(state, Driving):
        return Driving(robot, state.target, state.heard_at, state.current, state.current_at)
    return EStopped(robot, state.emg_at, state.emg_pending, state.emg_resends, state.heard_at)


def _approach(value: float, target: float, max_step: float | None) -> float:
    if max_step is None or abs(target - value) <= max_step:
        return target
    return value + math.copysign(max_step, target - value)
