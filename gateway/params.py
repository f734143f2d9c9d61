"""The gateway's parameters: what an operator may change on a running gateway, and what is shown but fixed.

Each value is checked and set on its own, as rclcpp's ``set_parameters`` (docs/ros2.md "ros2 param"); ``cmd_timeout``
is never switched off on a running robot; the wheel constants, poll rate and keep-alive are read-only: the odometry
and the calibration were made with them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

from blackmetal import robot_model as model
from blackmetal.schemas import Param, ParamValue

from .arbiter import Arbiter
from .safety import Governor
from .settings import TIME_LIMITS, GatewaySettings

#: The longest command timeout a parameter may set (the settings' own bound, for the same reason).
MAX_CMD_TIMEOUT_S = dict((name, limit) for name, limit, _ in TIME_LIMITS)["cmd_timeout"]
#: The shortest: below a few poll periods a commander at 10 Hz would brake between its commands.
MIN_CMD_TIMEOUT_S = 0.05
#: Acceleration limits beyond these are typos (the robot reaches 0.8 m/s in well under a second).
MAX_LINEAR_ACCEL = 50.0
MAX_ANGULAR_ACCEL = 200.0
#: The safety limits that change live; the accelerations' 0 is no limit.
_LIMIT_HELP = {
    "max_wheel_speed": "per-wheel speed limit, m/s; faster commands are scaled down keeping their curvature",
    "cmd_timeout": "brake after this many seconds without a command (the deadman); it cannot be switched off while running",
    "linear_accel": "acceleration limit of the forward speed, m/s^2; 0 is no limit",
    "angular_accel": "acceleration limit of the turn rate, rad/s^2; 0 is no limit",
}
#: A source's priority, as the settings take it.
PRIORITY_RANGE = (0, 255)


@dataclass(frozen=True, slots=True)
class _Live:
    """A parameter that changes live: how to read it, how to set an already checked value, and any check beyond its range."""

    kind: str
    description: str
    low: float
    high: float
    get: Callable[[], float]
    set: Callable[[float], None]
    refuse: Callable[[float], str | None] | None = None


class ParamTable:
    def __init__(self, settings: GatewaySettings, governor: Governor, arbiter: Arbiter) -> None:
        self.settings = settings
        self.governor = governor
        self.arbiter = arbiter
        self._live = self._live_params()

    def table(self) -> list[Param]:
        """Every parameter, live ones first, each with its value now."""
        live = [Param(name, spec.kind, spec.get(), spec.description, min=spec.low, max=spec.high) for name, spec in self._live.items()]
        return live + self._fixed()

    def set(self, name: str, value: ParamValue) -> str | None:
        """Set ``name`` to ``value``; the reason it is refused, if it is (nothing changes then)."""
        spec = self._live.get(name)
        if spec is None:
            fixed = {param.name for param in self._fixed()}
            if name in fixed:
                return f"{name} is read-only on a running gateway: set it in the gateway's settings and restart it"
            return f"no parameter {name!r}: the gateway's parameters are {', '.join(param.name for param in self.table())}"
        if isinstance(value, bool) or not isinstance(value, int if spec.kind == "integer" else (int, float)):
            return f"{name} takes {'an integer' if spec.kind == 'integer' else 'a number'}, got {value!r}"
        checked = value if spec.kind == "integer" else float(value)
        if not math.isfinite(checked) or not spec.low <= checked <= spec.high:
            return f"{name} must be within {spec.low:g}..{spec.high:g}, got {value!r}"
        reason = None if spec.refuse is None else spec.refuse(checked)
        if reason is not None:
            return reason
        spec.set(checked)
        return None

    def _live_params(self) -> dict[str, _Live]:
        governor, arbiter = self.governor, self.arbiter
        top_speed = max(model.MAX_WHEEL_SPEED, self.settings.max_wheel_speed)
        params = {
            name: _Live(
                "double", _LIMIT_HELP[name], low, high, partial(_limit_of, governor, name), partial(_set_limit, governor, name), refuse
            )
            for name, low, high, refuse in (
                ("max_wheel_speed", 0.01, top_speed, None),
                ("cmd_timeout", 0.0, MAX_CMD_TIMEOUT_S, _refuse_cmd_timeout),
                ("linear_accel", 0.0, MAX_LINEAR_ACCEL, None),
                ("angular_accel", 0.0, MAX_ANGULAR_ACCEL, None),
            )
        }
        for name in arbiter.names:
            params[f"sources.{name}.priority"] = _Live(
                "integer",
                f"priority of the command source {name!r} (the highest live source drives)",
                *PRIORITY_RANGE,
                partial(arbiter.priority_of, name),
                partial(_retune, arbiter, name, "priority"),
            )
            params[f"sources.{name}.timeout"] = _Live(
                "double",
                f"seconds after its last command that the source {name!r} stops counting as live",
                0.01,
                MAX_CMD_TIMEOUT_S,
                partial(arbiter.timeout_of, name),
                partial(_retune, arbiter, name, "timeout"),
            )
        return params

    def _fixed(self) -> list[Param]:
        s = self.settings
        fixed: list[tuple[str, str, ParamValue, str]] = [
            ("wheel_separation", "double", s.wheel_separation, "distance between the wheels, m"),
            ("wheel_radius", "double", model.WHEEL_RADIUS, "wheel radius, m"),
            ("impulses_left", "double", s.impulses_left, "calibrated impulses per metre, left wheel"),
            ("impulses_right", "double", s.impulses_right, "calibrated impulses per metre, right wheel"),
            ("poll_hz", "double", s.poll_hz, "wheel-speed polls per second"),
            ("keepalive", "double", s.keepalive, "an unchanged motion command is repeated this often, s"),
            ("max_command_hz", "double", s.max_command_hz, "cap on velocity commands per second to the robot"),
            ("release_key_only", "bool", s.release_key_only, "only <prefix>/estop/release releases the e-stop"),
            ("position_moves", "bool", s.position_moves, "<prefix>/wheels/move runs the robot's own position moves"),
            ("position_speed", "double", s.position_speed, "rim speed of the robot's position moves, m/s"),
            ("robot", "string", s.robot, "the robot's address"),
            ("prefix", "string", s.prefix, "the robot's key-expression prefix"),
        ]
        fixed += [
            (f"locks.{lock.name}.priority", "integer", lock.priority, f"priority up to which the lock {lock.name!r} blocks sources")
            for lock in self.arbiter.locks
        ]
        return [Param(name, kind, value, description, read_only=True) for name, kind, value, description in fixed]


def _retune(arbiter: Arbiter, name: str, field: str, value: float) -> None:
    arbiter.retune(name, **{field: value})


def _limit_of(governor: Governor, name: str) -> float:
    """A safety limit as the table shows it: read at call time (a set replaces the settings), None (off) as 0."""
    value = getattr(governor.settings, name)
    return 0.0 if value is None else value


def _set_limit(governor: Governor, name: str, value: float) -> None:
    """0 is off (None): only the accelerations can be set to 0, the other limits refuse it."""
    limit: Any = value or None
    governor.settings = replace(governor.settings, **{name: limit})


def _refuse_cmd_timeout(value: float) -> str | None:
    if float(value) == 0:
        return (
            "cmd_timeout 0 (no deadman) is refused on a running gateway: set cmd_timeout = 0 in its settings and restart it if you mean it"
        )
    if float(value) < MIN_CMD_TIMEOUT_S:
        return f"cmd_timeout must be at least {MIN_CMD_TIMEOUT_S:g} s (a commander at 10 Hz would brake between commands)"
    return None
