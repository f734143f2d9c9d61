"""The safety governor's vocabulary: its settings, its three states and what a state does next, as frozen values
(a decision made for a state object holds as long as that object is the state)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import Enum

from blackmetal.robot_model import MAX_WHEEL_SPEED, UNITY_GAIN, WHEEL_SEPARATION, WheelGain, WheelSpeeds

#: Pause before the first re-send of a command the robot did not take; it doubles up to RETRY_CAP_S.
RETRY_FIRST_S = 0.005
RETRY_CAP_S = 0.25
#: After a stop is accepted, the wheels may take this long to come to rest before the stop is asked for again.
STOP_GRACE_S = 0.5
#: Rim speed below which a wheel counts as standing (m/s).
STANDING_SPEED = 0.01
#: While an acceleration limit holds the twist back from the commanded one, it is stepped at least this often (s).
RAMP_STEP_S = 0.02

#: A body twist: (v m/s, w rad/s).
Velocity = tuple[float, float]
STILL: Velocity = (0.0, 0.0)


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
    #: Per-wheel correction of the commanded m/s: calibrated impulses per metre over the firmware's nominal ones.
    wheel_gain: WheelGain = UNITY_GAIN


class CommandReason(Enum):
    """Why a velocity command goes out; the core counts and reports by it."""

    NEW = "new"  # the wanted wheel speeds changed
    KEEPALIVE = "keepalive"  # unchanged motion, repeated before the robot's watchdog fires
    RETRY = "retry"  # the robot did not take the previous one
    STOP_AGAIN = "stop-again"  # the wheels still turn although the robot accepted a stop


@dataclass(frozen=True, slots=True)
class VelocityCommand:
    wheels: WheelSpeeds
    reason: CommandReason


@dataclass(frozen=True, slots=True)
class Sent:
    """The last velocity command written on this link, when, and its re-sends since the robot did not take it."""

    wheels: WheelSpeeds
    at: float
    resends: int = 0
    #: When it is re-sent next (None: no re-send planned).
    resend_at: float | None = None


@dataclass(frozen=True, slots=True)
class Robot:
    """What this link told the robot and heard back; every new link starts from nothing."""

    sent: Sent | None = None
    #: The wheel speeds the robot last accepted (RECIEVE_OK), and when.
    accepted: WheelSpeeds | None = None
    accepted_at: float = -math.inf
    #: The wheels turned at the last poll.
    moving: bool = False


@dataclass(frozen=True, slots=True)
class Offline:
    """No control link: nothing is sent and nothing is due; a latched e-stop stays latched for the next link."""

    estop: bool = False


@dataclass(frozen=True, slots=True)
class EStopped:
    """The e-stop is latched on a live link: EMG_STOP goes out, and again while the wheels still turn; never motion."""

    robot: Robot
    #: When EMG_STOP is due (pending) or was (written): the wheels get STOP_GRACE_S from then to come to rest.
    emg_at: float
    emg_pending: bool = True
    emg_resends: int = 0
    #: When the last valid cmd_vel was heard (the command timeout in health still counts from it).
    heard_at: float = -math.inf

    @property
    def recheck_at(self) -> float:
        """When EMG_STOP is asked for again because the wheels still turn (inf: they stand, or it is still to go out)."""
        return self.emg_at + STOP_GRACE_S if self.robot.moving and not self.emg_pending else math.inf

    def emg_again(self, now: float) -> EStopped:
        """EMG_STOP once more, after a pause that grows with each time."""
        resends = self.emg_resends + 1
        return replace(self, emg_at=now + retry_delay(resends), emg_pending=True, emg_resends=resends)


@dataclass(frozen=True, slots=True)
class Driving:
    """A live link, no e-stop: the twist goes out through the limits, the timeout, the ramp and the rate cap."""

    robot: Robot
    target: Velocity = STILL
    #: When ``target`` was commanded; the command timeout counts from it (-inf: a fresh cmd_vel is needed to move).
    heard_at: float = -math.inf
    #: The twist after the acceleration limits, as of ``current_at``; while it equals the target it holds from then on
    #: (``current_at`` moves only while it changes: whoever changes the target brings it up to now first).
    current: Velocity = STILL
    current_at: float = -math.inf


#: Everything the governor knows, as one value.
State = Offline | EStopped | Driving


@dataclass(frozen=True, slots=True)
class Due:
    """What a state does next with no new input, and from when (``at <= now``: now); no command: only a look again."""

    at: float
    command: VelocityCommand | None = None
    #: EMG_STOP then, ahead of any velocity.
    emg_stop: bool = False


NOTHING_DUE = Due(math.inf)
