"""The navigation service's live parameters: limits, tolerances, timeouts; their table on ``<prefix>/nav/params``.

Each value is checked and set on its own, as the gateway's parameters are (``gateway/params.py``, whose shape this
table follows without importing it: the services never import each other). The motion limits are the navigation's
own; what the controller uses is those clamped to the gateway's (:func:`effective_limits`), so a goal is never planned
faster than the gateway lets the robot go.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import NamedTuple

from blackmetal.schemas import ConfigError, GatewayParams, Param, ParamResult, ParamValue

from .controller import Limits


class ParamSpec(NamedTuple):
    """What a parameter means and the range it may take (inclusive)."""

    description: str
    low: float
    high: float


#: Every live parameter, in the order the table lists them. The ranges keep typos out (a 30 m/s robot, a 0 s timeout).
PARAM_SPECS: dict[str, ParamSpec] = {
    "max_speed": ParamSpec("forward speed limit of a goal, m/s (the gateway's max_wheel_speed bounds it too)", 0.01, 1.0),
    "max_turn": ParamSpec("turn rate limit of a goal, rad/s (the gateway's max_wheel_speed bounds it too)", 0.05, 8.0),
    "linear_accel": ParamSpec("acceleration of the forward speed, m/s^2 (at most the gateway's linear_accel)", 0.05, 50.0),
    "angular_accel": ParamSpec("acceleration of the turn rate, rad/s^2 (at most the gateway's angular_accel)", 0.1, 200.0),
    "xy_tolerance": ParamSpec("a goal is reached within this distance of its position, m", 0.001, 1.0),
    "yaw_tolerance": ParamSpec("a goal is reached within this angle of its yaw, rad", 0.001, math.pi),
    "max_goal_distance": ParamSpec("goals farther than this from the robot are refused, m", 0.1, 10_000.0),
    "reverse_distance": ParamSpec("a goal behind the robot and at most this far is driven to backwards, m (0: never)", 0.0, 10.0),
    "override_timeout": ParamSpec("a goal is aborted when another source drives for longer than this, s", 0.0, 60.0),
    "pose_timeout": ParamSpec("a goal is aborted (and the robot stopped) after this long without a pose, s", 0.05, 5.0),
    "no_progress_timeout": ParamSpec("a goal is aborted when it comes no closer for this long, s", 0.5, 600.0),
    "feedback_hz": ParamSpec("feedback published per second while a goal runs", 5.0, 50.0),
}


@dataclass(frozen=True, slots=True)
class NavParams:
    """The navigation's parameters (defaults: a careful indoor robot). Frozen: a set makes a new record."""

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
        """ConfigError naming the first value out of its range (settings call this; a live set checks each value)."""
        for item in fields(self):
            reason = _refusal(item.name, getattr(self, item.name))
            if reason is not None:
                raise ConfigError(f"nav setting {reason}")

    def with_values(self, values: dict[str, ParamValue]) -> tuple[NavParams, list[ParamResult]]:
        """These parameters with ``values`` set, each on its own, and each one's result (a refusal says why)."""
        params, results = self, []
        for name, value in values.items():
            params, refused = params.with_value(name, value)
            results.append(ParamResult(name, refused is None, refused or ""))
        return params, results

    def with_value(self, name: str, value: ParamValue) -> tuple[NavParams, str | None]:
        """These parameters with ``name`` set to ``value``, or themselves and the reason it is refused."""
        if name not in PARAM_SPECS:
            if name in READ_ONLY:
                return self, f"{name} is read-only: it follows the gateway's parameters and the navigation's own"
            return self, f"no parameter {name!r}: the navigation's parameters are {', '.join(PARAM_SPECS)}"
        reason = _refusal(name, value)
        if reason is not None:
            return self, reason
        return replace(self, **{name: float(value)}), None

    def table(self, limits: Limits) -> list[Param]:
        """Every parameter with its value now, live ones first, then the limits the controller uses (read-only)."""
        live = [
            Param(name, "double", getattr(self, name), spec.description, min=spec.low, max=spec.high) for name, spec in PARAM_SPECS.items()
        ]
        fixed = [
            Param(name, "double", getattr(limits, field), description, read_only=True) for name, (field, description) in READ_ONLY.items()
        ]
        return live + fixed


#: The read-only rows: the limits the controller plans with (the navigation's, clamped to the gateway's).
READ_ONLY: dict[str, tuple[str, str]] = {
    "effective.max_speed": ("max_speed", "forward speed limit in use, m/s: max_speed within the gateway's wheel speed limit"),
    "effective.max_turn": ("max_turn", "turn rate limit in use, rad/s: max_turn within the gateway's wheel speed limit"),
    "effective.linear_accel": ("linear_accel", "acceleration in use, m/s^2: linear_accel within the gateway's"),
    "effective.angular_accel": ("angular_accel", "angular acceleration in use, rad/s^2: angular_accel within the gateway's"),
}


def _refusal(name: str, value: object) -> str | None:
    spec = PARAM_SPECS[name]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"{name} takes a number, got {value!r}"
    if not math.isfinite(value) or not spec.low <= value <= spec.high:
        return f"{name} must be within {spec.low:g}..{spec.high:g}, got {value!r}"
    return None


class GatewayLimits(NamedTuple):
    """The gateway's limits that bound a goal's motion (None: the gateway sets no acceleration limit)."""

    max_wheel_speed: float | None = None
    linear_accel: float | None = None
    angular_accel: float | None = None
    wheel_separation: float = 0.5

    @classmethod
    def of(cls, message: GatewayParams) -> GatewayLimits:
        """The limits in a ``gateway/params`` message; a row missing or not a positive number keeps its default."""
        values = {p.name: p.value for p in message.params}

        def positive(name: str) -> float | None:
            value = values.get(name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                return None
            return float(value)

        return cls(positive("max_wheel_speed"), positive("linear_accel"), positive("angular_accel"), positive("wheel_separation") or 0.5)


def effective_limits(params: NavParams, gateway: GatewayLimits) -> Limits:
    """The navigation's limits within the gateway's: a wheel never asked beyond max_wheel_speed, no ramp the gateway cuts."""
    max_speed, max_turn = params.max_speed, params.max_turn
    linear_accel, angular_accel = params.linear_accel, params.angular_accel
    if gateway.max_wheel_speed is not None:
        max_speed = min(max_speed, gateway.max_wheel_speed)
        max_turn = min(max_turn, gateway.max_wheel_speed / (gateway.wheel_separation / 2))
    if gateway.linear_accel is not None:
        linear_accel = min(linear_accel, gateway.linear_accel)
    if gateway.angular_accel is not None:
        angular_accel = min(angular_accel, gateway.angular_accel)
    return Limits(
        max_speed=max_speed,
        max_turn=max_turn,
        linear_accel=linear_accel,
        angular_accel=angular_accel,
        max_wheel_speed=gateway.max_wheel_speed,
        wheel_separation=gateway.wheel_separation,
    )
