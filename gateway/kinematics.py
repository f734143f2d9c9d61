"""Differential-drive kinematics: a body twist to wheel rim speeds, keeping the curvature."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class WheelSpeeds:
    """Wheel rim speeds in m/s, natural sign (forward positive on both wheels)."""

    right: float
    left: float

    def rounded(self) -> "WheelSpeeds":
        """As the wire carries them (6 decimals), so equal commands compare equal."""
        return WheelSpeeds(round(self.right, 6) + 0.0, round(self.left, 6) + 0.0)

    @property
    def is_zero(self) -> bool:
        return self.right == 0.0 and self.left == 0.0


ZERO = WheelSpeeds(0.0, 0.0)


def twist_to_wheels(v: float, w: float, separation: float, max_wheel_speed: float) -> tuple[WheelSpeeds, bool]:
    """Wheel speeds for forward speed ``v`` (m/s) and turn rate ``w`` (rad/s, + is left).

    ``right = v + w*L/2``, ``left = v - w*L/2``. If either exceeds
    ``max_wheel_speed``, both are scaled by the same factor so the robot
    follows the same arc, only slower (clamping each wheel alone would bend
    the path). Returns the speeds and whether they were scaled.
    """
    half = 0.5 * w * separation
    right = v + half
    left = v - half
    peak = max(abs(right), abs(left))
    if peak <= max_wheel_speed:
        return WheelSpeeds(right, left), False
    scale = max_wheel_speed / peak
    return WheelSpeeds(right * scale, left * scale), True


def wheels_to_twist(speeds: WheelSpeeds, separation: float) -> tuple[float, float]:
    """Forward speed and turn rate of wheel speeds (the inverse of :func:`twist_to_wheels`)."""
    return 0.5 * (speeds.right + speeds.left), (speeds.right - speeds.left) / separation
