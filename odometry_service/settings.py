"""The odometry service's settings (same precedence rules as the gateway's)."""

from __future__ import annotations

from dataclasses import dataclass, field

from gateway.errors import ConfigError
from gateway.zenoh_config import MODES, validate_prefix
from schemas import robot as facts

from .core import OdometryParams
from .errors import OdometryError


@dataclass(slots=True)
class OdometrySettings:
    wheel_separation: float = facts.WHEEL_SEPARATION
    impulses_left: float = facts.IMPULSES_PER_METER_LEFT
    impulses_right: float = facts.IMPULSES_PER_METER_RIGHT
    mirror_right: bool = True
    max_wheel_speed: float = facts.MAX_WHEEL_SPEED
    filter_alpha: float = 0.3
    max_gap: float = 0.5
    prefix: str = facts.DEFAULT_PREFIX
    mode: str | None = None
    connect: list[str] = field(default_factory=list)
    listen: list[str] = field(default_factory=list)
    config: str | None = None
    no_multicast_scouting: bool = False

    def params(self) -> OdometryParams:
        return OdometryParams(
            wheel_separation=self.wheel_separation,
            impulses_per_meter_left=self.impulses_left,
            impulses_per_meter_right=self.impulses_right,
            mirror_right=self.mirror_right,
            max_wheel_speed=self.max_wheel_speed,
            filter_alpha=self.filter_alpha,
            max_gap=self.max_gap,
        )

    def check(self) -> None:
        try:
            self.params().check()
        except OdometryError as exc:
            raise ConfigError(str(exc)) from None
        if self.mode is not None and self.mode not in MODES:
            raise ConfigError(f"mode must be one of {MODES}")
        validate_prefix(self.prefix)


def add_odometry_arguments(parser) -> None:  # type: ignore[no-untyped-def]
    """Pipeline options shared by ``blackmetal odometry`` and ``blackmetal replay``."""
    parser.add_argument("--settings", metavar="FILE", help="settings file (TOML or JSON5)")
    parser.add_argument("--wheel-separation", type=float, help="m (default 0.5)")
    parser.add_argument("--impulses-left", type=float, help="impulses per metre, left wheel (default 1012.53636364)")
    parser.add_argument("--impulses-right", type=float, help="impulses per metre, right wheel (default 1053.67588345)")
    parser.add_argument(
        "--no-mirror-right", dest="mirror_right", action="store_const", const=False, help="the right encoder is not mirrored"
    )
    parser.add_argument("--max-wheel-speed", type=float, help="m/s; readings above are glitches (default 0.8)")
    parser.add_argument("--filter-alpha", type=float, help="low-pass strength in [0, 1), 0 = off (default 0.3)")
    parser.add_argument("--max-gap", type=float, help="do not integrate across gaps longer than this, s (default 0.5)")
