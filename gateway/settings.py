"""The gateway's settings: one typed object, see :mod:`gateway.config` for precedence."""

from __future__ import annotations

from dataclasses import dataclass, field

from schemas import robot as facts

from .errors import ConfigError
from .safety import SafetySettings
from .zenoh_config import MODES, validate_prefix


@dataclass(slots=True)
class GatewaySettings:
    robot: str = "127.0.0.1"
    control_port: int = facts.CONTROL_PORT
    log_port: int = facts.LOG_PORT
    poll_hz: float = 50.0
    wheel_separation: float = facts.WHEEL_SEPARATION
    max_wheel_speed: float = facts.MAX_WHEEL_SPEED
    cmd_timeout: float = 0.5
    keepalive: float = 5.0
    linear_accel: float | None = None
    angular_accel: float | None = None
    max_command_hz: float = 500.0
    prefix: str = facts.DEFAULT_PREFIX
    #: A request unanswered this long is given up (the original driver used 200 ms).
    reply_timeout: float = 0.5
    #: The control link is declared dead when requests go unanswered this long.
    silence_timeout: float = 1.0
    #: The log link is declared dead after this long without a report (the robot sends ~1 Hz).
    log_silence_timeout: float = 3.5
    connect_timeout: float = 1.0
    health_period: float = 1.0
    # Zenoh
    mode: str | None = None
    connect: list[str] = field(default_factory=list)
    listen: list[str] = field(default_factory=list)
    config: str | None = None
    no_multicast_scouting: bool = False

    def check(self) -> None:
        """Refuse settings that cannot work, naming the setting."""
        positive = {
            "poll_hz": self.poll_hz,
            "wheel_separation": self.wheel_separation,
            "max_wheel_speed": self.max_wheel_speed,
            "keepalive": self.keepalive,
            "reply_timeout": self.reply_timeout,
            "silence_timeout": self.silence_timeout,
            "log_silence_timeout": self.log_silence_timeout,
            "connect_timeout": self.connect_timeout,
            "health_period": self.health_period,
            "max_command_hz": self.max_command_hz,
        }
        for name, value in positive.items():
            if not value > 0:
                raise ConfigError(f"{name} must be positive, got {value}")
        if self.poll_hz > 1000:
            raise ConfigError(f"poll_hz {self.poll_hz} is beyond 1000 Hz")
        if self.max_wheel_speed > 1.0:
            raise ConfigError(f"max_wheel_speed {self.max_wheel_speed} is beyond the robot's wire limit of 1.0 m/s")
        if self.keepalive >= facts.ROBOT_WATCHDOG_S:
            raise ConfigError(f"keepalive {self.keepalive} s must be shorter than the robot's {facts.ROBOT_WATCHDOG_S} s watchdog")
        if self.cmd_timeout < 0:
            raise ConfigError("cmd_timeout must be >= 0 (0 disables it)")
        for name in ("linear_accel", "angular_accel"):
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise ConfigError(f"{name} must be positive when set")
        for name in ("control_port", "log_port"):
            if not 1 <= getattr(self, name) <= 65535:
                raise ConfigError(f"{name} must be a TCP port 1-65535")
        if self.mode is not None and self.mode not in MODES:
            raise ConfigError(f"mode must be one of {MODES}")
        validate_prefix(self.prefix)

    def safety(self) -> SafetySettings:
        return SafetySettings(
            wheel_separation=self.wheel_separation,
            max_wheel_speed=self.max_wheel_speed,
            cmd_timeout=self.cmd_timeout,
            keepalive=self.keepalive,
            linear_accel=self.linear_accel,
            angular_accel=self.angular_accel,
            max_command_hz=self.max_command_hz,
        )
