"""What velocity the robot should get, and when: limits, timeout, e-stop, dedup, keep-alive, confirmed stops.

Pure and clock-injected: the robot connection calls
:meth:`Governor.next_command` and :meth:`Governor.emg_stop_due` on every
event and at every deadline (:meth:`Governor.next_deadline`) and sends what
they return; it reports the robot's answers back (:meth:`on_accepted`,
:meth:`on_dropped`, :meth:`on_emg_stop_dropped`) and the wheel motion it
polls (:meth:`observe_motion`). Nothing here knows about sockets or Zenoh.

Stopping is confirmed, not assumed: a command the robot did not accept
(FULL_BUFFER, or no reply) is re-sent after a growing pause (5 ms, 10 ms,
... at most 250 ms, so never more than a few dozen a second); a motion
command is given up after ``full_buffer_retries``, a stop never is. While
the robot's wheels turn although it accepted a stop, the stop is asked for
again, spaced the same way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from blackmetal.robot_model import MAX_WHEEL_SPEED, STANDSTILL, UNITY_GAIN, WHEEL_SEPARATION, WheelGain, WheelSpeeds, twist_to_wheels
from blackmetal.schemas import Twist

#: Pause before the first re-send of a command the robot did not take; it doubles up to RETRY_CAP_S.
RETRY_FIRST_S = 0.005
RETRY_CAP_S = 0.25
#: After a stop is accepted, the wheels may take this long to come to rest before the stop is asked for again.
STOP_GRACE_S = 0.5
#: Rim speed below which a wheel counts as standing (m/s).
STANDING_SPEED = 0.01


def retry_delay(attempt: int) -> float:
    """Pause before re-send number ``attempt`` (1, 2, ...): 5 ms doubling, at most 250 ms."""
    return min(RETRY_FIRST_S * 2.0 ** max(attempt - 1, 0), RETRY_CAP_S)


@dataclass(frozen=True, slots=True)
class SafetySettings:
    wheel_separation: float = WHEEL_SEPARATION
    #: Per-wheel limit (m/s); faster commands are scaled down, keeping the curvature.
    max_wheel_speed: float = MAX_WHEEL_SPEED
    #: Brake when no valid cmd_vel arrived for this long (s); 0 disables.
    cmd_timeout: float = 0.5
    #: Repeat an unchanged, non-zero command this often so the robot's 10 s watchdog never fires (s).
    keepalive: float = 5.0
    #: Optional acceleration limits on the body twist (m/s^2, rad/s^2); None = off.
    linear_accel: float | None = None
    angular_accel: float | None = None
    #: A cmd_vel beyond these is not a command but a client bug: rejected, not scaled.
    plausible_linear: float = 10.0
    plausible_angular: float = 50.0
    #: How often a motion command the robot did not take is re-sent before giving up until the next change.
    full_buffer_retries: int = 5
    #: At most this many velocity commands per second reach the robot; a flood is coalesced to the latest.
    max_command_hz: float = 500.0
    #: Per-wheel correction of the commanded m/s: calibrated impulses per metre over the
    #: nominal ones the robot's firmware uses, so a wheel larger than its drawing is asked for less.
    wheel_gain: WheelGain = UNITY_GAIN


class Mode(Enum):
    """What the governor is doing; every decision starts from it."""

    OFFLINE = "offline"  # no control link: nothing is sent and nothing is due
    ESTOP = "estop"  # the e-stop is latched: EMG_STOP (again while the wheels still turn), never motion
    DRIVING = "driving"  # limits, command timeout, coalescing, retries, keep-alive, confirmed stops


class CommandReason(Enum):
    """Why a velocity command goes out; the connection counts and reports by it."""

    NEW = "new"  # the wanted wheel speeds changed
    KEEPALIVE = "keepalive"  # unchanged motion, repeated before the robot's watchdog fires
    RETRY = "retry"  # the robot did not take the previous one
    STOP_AGAIN = "stop-again"  # the wheels still turn although the robot accepted a stop


@dataclass(frozen=True, slots=True)
class VelocityCommand:
    """A velocity to send now, and why."""

    wheels: WheelSpeeds
    reason: CommandReason


class Governor:
    """The gateway's safety state machine."""

    def __init__(self, settings: SafetySettings, now: float) -> None:
        self.settings = settings
        self.estop = False
        self.link_up = False
        self.target = (0.0, 0.0)  # wanted (v, w)
        self.current = (0.0, 0.0)  # after acceleration limits
        self.last_cmd_at = -math.inf
        #: The last command was scaled down to the wheel limit (keeping its curvature).
        self.scaled = False
        #: The wheel speeds the robot last accepted (None: nothing accepted on this connection).
        self.accepted: WheelSpeeds | None = None
        self.accepted_at = -math.inf
        #: An EMG_STOP is to be sent (at or after ``_emg_at``).
        self.emg_stop_needed = False
        self._emg_at = -math.inf
        self._emg_attempts = 0
        self._last_update = now
        self._last_sent: WheelSpeeds | None = None
        self._last_sent_at = -math.inf
        self._attempts = 0  # re-sends of _last_sent so far
        self._retry_at: float | None = None
        self._moving = False
        #: When a rate-limited command may go out (None: nothing is waiting).
        self.hold_until: float | None = None

    # ------------------------------------------------------------------ inputs

    def on_twist(self, twist: Twist, now: float) -> str | None:
        """Accept a velocity command given at ``now``, or return why it is refused (the robot's command stays as it was)."""
        reason = self.refusal(twist)
        if reason is None:
            self.take_twist(twist, now)
        return reason

    def take_twist(self, twist: Twist, now: float) -> None:
        """A command :meth:`refusal` has just passed becomes the target (the caller asked, with this state)."""
        self.target = (twist.linear.x, twist.angular.z)
        self.last_cmd_at = now

    def refusal(self, twist: Twist) -> str | None:
        """Why a velocity command would be refused now, if it would."""
        if self.estop:
            return 'emergency stop is engaged: cmd_vel refused until {"engaged": false} is put on estop'
        if not self.link_up:
            return "robot control link is down: cmd_vel refused, not queued"
        v, w = twist.linear.x, twist.angular.z
        s = self.settings
        if abs(v) > s.plausible_linear:
            return f"linear.x {v!r} m/s is beyond any plausible command (|v| <= {s.plausible_linear})"
        if abs(w) > s.plausible_angular:
            return f"angular.z {w!r} rad/s is beyond any plausible command (|w| <= {s.plausible_angular})"
        return None

    def on_estop(self, engaged: bool, now: float) -> None:
        if engaged:
            if not self.estop:
                self._request_emg_stop(now)
            self.estop = True
            self.target = self.current = (0.0, 0.0)
            self._last_sent = STANDSTILL  # EMG_STOP stops the wheels; no velocity command needed
            self._retry_at = None
        else:
            self.estop = False
            self.emg_stop_needed = False
            self.last_cmd_at = -math.inf  # a fresh cmd_vel is needed to move again

    def brake(self) -> None:
        """Stop now, whatever was commanded (a conflict); a fresh cmd_vel is needed to move again."""
        self.target = (0.0, 0.0)
        self.last_cmd_at = -math.inf

    def on_link_up(self, now: float) -> None:
        """A new connection: the robot gets zero velocity (and EMG_STOP if latched), never an old motion."""
        self.link_up = True
        self._reset_motion()
        if self.estop:
            self._request_emg_stop(now)

    def on_link_down(self) -> None:
        self.link_up = False
        self._reset_motion()
        self.emg_stop_needed = False

    def _reset_motion(self) -> None:
        self.target = self.current = (0.0, 0.0)
        self.last_cmd_at = -math.inf
        self._last_sent = None
        self.accepted = None
        self._attempts = 0
        self._retry_at = None
        self._moving = False

    def _request_emg_stop(self, now: float) -> None:
        self.emg_stop_needed = True
        self._emg_at = now
        self._emg_attempts = 0

    # ------------------------------------------------------------------ the robot's answers

    def on_accepted(self, wheels: WheelSpeeds, now: float) -> None:
        """The robot answered RECIEVE_OK to a velocity command."""
        self.accepted = wheels
        self.accepted_at = now
        if wheels == self._last_sent:
            self._attempts = 0
            self._retry_at = None

    def on_dropped(self, wheels: WheelSpeeds, now: float) -> str | None:
        """The robot did not take ``wheels`` (FULL_BUFFER, or no reply). Returns a reason to report, if any."""
        if wheels != self._last_sent or self._retry_at is not None:
            return None  # superseded by a newer command, or a re-send is already planned
        if not wheels.is_zero and self._attempts >= self.settings.full_buffer_retries:
            return f"robot did not take the velocity command {self._attempts + 1} times: given up until the command changes"
        self._attempts += 1
        self._retry_at = now + retry_delay(self._attempts)
        return None

    def on_emg_stop_dropped(self, now: float) -> None:
        """EMG_STOP was not taken: send it again after a growing pause, for as long as the stop is engaged."""
        if self.estop:
            self._emg_attempts += 1
            self.emg_stop_needed = True
            self._emg_at = now + retry_delay(self._emg_attempts)

    def on_emg_stop_sent(self) -> None:
        self.emg_stop_needed = False

    def observe_motion(self, left: float, right: float, now: float) -> None:
        """The wheels' rim speeds as polled (m/s)."""
        self._moving = max(abs(left), abs(right)) > STANDING_SPEED

    # ------------------------------------------------------------------ output

    @property
    def mode(self) -> Mode:
        if not self.link_up:
            return Mode.OFFLINE
        return Mode.ESTOP if self.estop else Mode.DRIVING

    def timed_out(self, now: float) -> bool:
        """True while no valid cmd_vel arrived within the command timeout."""
        timeout = self.settings.cmd_timeout
        return timeout > 0 and now >= self.last_cmd_at + timeout

    def emg_stop_due(self, now: float) -> bool:
        """True when an EMG_STOP should go out now (before any velocity command)."""
        return self.link_up and self.emg_stop_needed and now >= self._emg_at

    def _unwanted_motion_at(self) -> float:
        """When the robot, moving although it accepted a stop, should be asked to stop again (inf: not needed)."""
        if not self._moving or self._last_sent is None or not self._last_sent.is_zero:
            return math.inf
        if self.accepted is None or not self.accepted.is_zero or self._retry_at is not None:
            return math.inf
        return max(self.accepted_at + STOP_GRACE_S, self._last_sent_at + RETRY_CAP_S)

    def _estop_recheck_at(self) -> float:
        """With the e-stop latched: when to ask for EMG_STOP again because the wheels still turn (inf: not needed)."""
        if self._moving and not self.emg_stop_needed:
            return self._emg_at + STOP_GRACE_S
        return math.inf

    def unwanted_motion(self, now: float) -> bool:
        return now >= self._unwanted_motion_at()

    def next_command(self, now: float, congested: bool = False) -> VelocityCommand | None:
        """The velocity to send now, if any; call on every event and every deadline.

        ``congested``: the robot is behind on its replies; motion waits (the
        next reply calls again), a stop never does.
        """
        dt = max(0.0, now - self._last_update)
        self._last_update = now
        mode = self.mode
        if mode is Mode.OFFLINE:
            return None
        if mode is Mode.ESTOP:
            if now >= self._estop_recheck_at():
                self.on_emg_stop_dropped(now)  # EMG_STOP taken but the wheels still turn: ask again
            return None
        if self.target != (0.0, 0.0) and self.timed_out(now):
            self.target = (0.0, 0.0)  # brake
        self.current = self._ramp(self.current, self.target, dt)
        s = self.settings
        wheels, self.scaled = twist_to_wheels(*self.current, s.wheel_separation, s.max_wheel_speed)
        if not s.wheel_gain.is_unity:
            wheels = wheels.scaled(s.wheel_gain)
        wheels = wheels.rounded()
        if congested and not wheels.is_zero:
            return None
        if wheels != self._last_sent:
            earliest = self._last_sent_at + 1.0 / s.max_command_hz
            if now < earliest and self._last_sent is not None:
                self.hold_until = earliest  # coalesce: the latest wanted command goes out then
                return None
            self.hold_until = None
            self._attempts = 0
            self._retry_at = None
            return self._sent(wheels, now, CommandReason.NEW)
        self.hold_until = None
        if self._retry_at is not None and now >= self._retry_at:
            self._retry_at = None
            return self._sent(wheels, now, CommandReason.RETRY)
        if self.unwanted_motion(now):
            return self._sent(wheels, now, CommandReason.STOP_AGAIN)
        if not wheels.is_zero and now >= self._last_sent_at + s.keepalive:
            return self._sent(wheels, now, CommandReason.KEEPALIVE)
        return None

    def _sent(self, wheels: WheelSpeeds, now: float, reason: CommandReason) -> VelocityCommand:
        self._last_sent = wheels
        self._last_sent_at = now
        return VelocityCommand(wheels, reason)

    def next_deadline(self, congested: bool = False) -> float:
        """When :meth:`next_command` or :meth:`emg_stop_due` may next have something to send without a new input.

        ``congested`` as for :meth:`next_command`: then only what a stop needs counts (motion waits for a reply).
        """
        mode = self.mode
        if mode is Mode.OFFLINE:
            return math.inf
        deadline = self._emg_at if self.emg_stop_needed else math.inf
        if mode is Mode.ESTOP:
            return min(deadline, self._estop_recheck_at())
        s = self.settings
        if self.target != (0.0, 0.0) and s.cmd_timeout > 0:
            deadline = min(deadline, self.last_cmd_at + s.cmd_timeout)
        deadline = min(deadline, self._unwanted_motion_at())
        stopping = self._last_sent is not None and self._last_sent.is_zero
        if congested and not (stopping and self.target == (0.0, 0.0)):
            return deadline  # motion waits for the robot's replies, which call again
        if self.hold_until is not None:
            deadline = min(deadline, self.hold_until)
        if self._retry_at is not None:
            deadline = min(deadline, self._retry_at)
        if self._last_sent is not None and not self._last_sent.is_zero:
            deadline = min(deadline, self._last_sent_at + s.keepalive)
        if self.current != self.target:  # ramping under an acceleration limit
            deadline = min(deadline, self._last_update + 0.02)
        return deadline

    def _ramp(self, current: tuple[float, float], target: tuple[float, float], dt: float) -> tuple[float, float]:
        s = self.settings
        v = _approach(current[0], target[0], None if s.linear_accel is None else s.linear_accel * dt)
        w = _approach(current[1], target[1], None if s.angular_accel is None else s.angular_accel * dt)
        return v, w


def _approach(value: float, target: float, max_step: float | None) -> float:
    if max_step is None or abs(target - value) <= max_step:
        return target
    return value + math.copysign(max_step, target - value)
