"""What velocity the robot should get, and when: limits, timeout, e-stop, dedup, keep-alive.

Pure and clock-injected: the robot connection calls
:meth:`Governor.next_command` on every event and at every deadline
(:meth:`Governor.next_deadline`) and sends what it returns. Nothing here
knows about sockets or Zenoh.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from blackmetal.robot_model import MAX_WHEEL_SPEED, STANDSTILL, WHEEL_SEPARATION, WheelSpeeds, twist_to_wheels
from schemas import Twist


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
    #: How often a command answered FULL_BUFFER is re-sent before giving up until the next change.
    full_buffer_retries: int = 5
    #: At most this many velocity commands per second reach the robot; a flood is coalesced to the latest.
    max_command_hz: float = 500.0


@dataclass(frozen=True, slots=True)
class VelocityCommand:
    """A velocity to send now, and why (``new``, ``keepalive``, ``retry``)."""

    wheels: WheelSpeeds
    reason: str


class Governor:
    """The gateway's safety state machine."""

    def __init__(self, settings: SafetySettings, now: float) -> None:
        self.settings = settings
        self.estop = False
        self.link_up = False
        self.target = (0.0, 0.0)  # wanted (v, w)
        self.current = (0.0, 0.0)  # after acceleration limits
        self.last_cmd_at = -math.inf
        self.scaled = False
        self.emg_stop_needed = False
        self._last_update = now
        self._last_sent: WheelSpeeds | None = None
        self._last_sent_at = -math.inf
        self._retries = 0
        self._retry_pending = False
        #: When a rate-limited command may go out (None: nothing is waiting).
        self.hold_until: float | None = None

    # ------------------------------------------------------------------ inputs

    def on_twist(self, twist: Twist, now: float) -> str | None:
        """Accept a velocity command, or return why it is refused (the robot's command stays as it was)."""
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
        self.target = (v, w)
        self.last_cmd_at = now
        return None

    def on_estop(self, engaged: bool) -> None:
        if engaged:
            if not self.estop:
                self.emg_stop_needed = True
            self.estop = True
            self.target = self.current = (0.0, 0.0)
            self._last_sent = STANDSTILL  # EMG_STOP stops the wheels; no velocity command needed
        else:
            self.estop = False
            self.last_cmd_at = -math.inf  # a fresh cmd_vel is needed to move again

    def on_link_up(self) -> None:
        """A new connection: the robot gets zero velocity (and EMG_STOP if latched), never an old motion."""
        self.link_up = True
        self._reset_motion()
        self.emg_stop_needed = self.estop

    def on_link_down(self) -> None:
        self.link_up = False
        self._reset_motion()

    def _reset_motion(self) -> None:
        self.target = self.current = (0.0, 0.0)
        self.last_cmd_at = -math.inf
        self._last_sent = None
        self._retries = 0

    def on_full_buffer(self, wheels: WheelSpeeds) -> bool:
        """The robot dropped ``wheels``; True if it will be re-sent (bounded retries)."""
        if wheels != self._last_sent:
            return False  # already superseded by a newer command
        if self._retries >= self.settings.full_buffer_retries:
            return False  # give up until the command changes or the keep-alive is due
        self._retries += 1
        self._retry_pending = True
        return True

    def on_acknowledged(self, wheels: WheelSpeeds) -> None:
        if wheels == self._last_sent:
            self._retries = 0

    def on_emg_stop_dropped(self) -> None:
        """EMG_STOP was answered FULL_BUFFER: send it again."""
        if self.estop:
            self.emg_stop_needed = True

    # ------------------------------------------------------------------ output

    def timed_out(self, now: float) -> bool:
        """True while no valid cmd_vel arrived within the command timeout."""
        timeout = self.settings.cmd_timeout
        return timeout > 0 and now >= self.last_cmd_at + timeout

    def next_command(self, now: float) -> VelocityCommand | None:
        """The velocity to send now, if any; call on every event and every tick."""
        dt = max(0.0, now - self._last_update)
        self._last_update = now
        if not self.link_up or self.estop:
            return None
        if self.target != (0.0, 0.0) and self.timed_out(now):
            self.target = (0.0, 0.0)  # brake
        self.current = self._ramp(self.current, self.target, dt)
        s = self.settings
        wheels, self.scaled = twist_to_wheels(*self.current, s.wheel_separation, s.max_wheel_speed)
        wheels = wheels.rounded()
        if wheels != self._last_sent and not self._retry_pending:
            earliest = self._last_sent_at + 1.0 / s.max_command_hz
            if now < earliest and self._last_sent is not None:
                self.hold_until = earliest  # coalesce: the latest wanted command goes out then
                return None
        self.hold_until = None
        if self._retry_pending:
            self._retry_pending = False
            if wheels == self._last_sent:
                return self._sent(wheels, now, "retry")
        if wheels != self._last_sent:
            return self._sent(wheels, now, "new")
        if not wheels.is_zero and now >= self._last_sent_at + s.keepalive:
            return self._sent(wheels, now, "keepalive")
        return None

    def _sent(self, wheels: WheelSpeeds, now: float, reason: str) -> VelocityCommand:
        if wheels != self._last_sent:
            self._retries = 0
        self._last_sent = wheels
        self._last_sent_at = now
        return VelocityCommand(wheels, reason)

    def _ramp(self, current: tuple[float, float], target: tuple[float, float], dt: float) -> tuple[float, float]:
        s = self.settings
        v = _approach(current[0], target[0], None if s.linear_accel is None else s.linear_accel * dt)
        w = _approach(current[1], target[1], None if s.angular_accel is None else s.angular_accel * dt)
        return v, w

    def next_deadline(self) -> float:
        """When :meth:`next_command` may next have something to send without a new input."""
        deadline = math.inf
        if not self.link_up or self.estop:
            return deadline
        if self.hold_until is not None:
            deadline = self.hold_until
        s = self.settings
        if self.target != (0.0, 0.0) and s.cmd_timeout > 0:
            deadline = min(deadline, self.last_cmd_at + s.cmd_timeout)
        if self._last_sent is not None and not self._last_sent.is_zero:
            deadline = min(deadline, self._last_sent_at + s.keepalive)
        if self.current != self.target:  # ramping under an acceleration limit
            deadline = min(deadline, self._last_update + 0.02)
        return deadline

    @property
    def wheels_sent(self) -> WheelSpeeds | None:
        return self._last_sent


def _approach(value: float, target: float, max_step: float | None) -> float:
    if max_step is None or abs(target - value) <= max_step:
        return target
    return value + math.copysign(max_step, target - value)
