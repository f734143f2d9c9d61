"""PLACEHOLDER (the core helper's nav/params.py replaces it): the navigation's live parameters, their defaults."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class NavParams:
    max_speed: float = 0.3
    max_turn: float = 1.2
    linear_accel: float = 0.5
    angular_accel: float = 2.0
    xy_tolerance: float = 0.01
    yaw_tolerance: float = 0.01745
    max_goal_distance: float = 100.0
    override_timeout: float = 2.0
    pose_timeout: float = 0.3
    no_progress_timeout: float = 10.0
    feedback_hz: float = 10.0
