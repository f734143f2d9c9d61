"""PLACEHOLDER (the core helper's nav/params.py replaces it): the navigation's live parameters, their defaults."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from blackmetal.schemas import ConfigError

#: Parameters that may be zero (0: never reverse; 0: abort at once when overridden).
MAY_BE_ZERO = ("reverse_distance", "override_timeout")


@dataclass(frozen=True, slots=True)
class NavParams:
    max_speed: float = 0.3
    max_turn: float = 1.2
    linear_accel: float = 0.5
    angular_accel: float = 2.0
    xy_tolerance: float = 0.01
    yaw_tolerance: float = math.radians(1.0)
    max_goal_distance: float = 100.0
    reverse_distance: float = 1.0
    override_timeout: float = 2.0
    pose_timeout: float = 0.3
    no_progress_timeout: float = 10.0
    feedback_hz: float = 10.0

    def check(self) -> None:
        """ConfigError naming the first value out of its range."""
        for item in fields(self):
            value = getattr(self, item.name)
            low = 5.0 if item.name == "feedback_hz" else 0.0
            if not math.isfinite(value) or value < low or (value == low and item.name not in MAY_BE_ZERO):
                raise ConfigError(f"nav setting {item.name} must be within its range, got {value!r}")
