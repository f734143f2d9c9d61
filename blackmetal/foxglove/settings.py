"""``blackmetal foxglove`` settings: one typed model, the same precedence rules as every service."""

from __future__ import annotations

from dataclasses import dataclass, field

from blackmetal.runtime.settings import setting
from blackmetal.runtime.zenoh_setup import ZenohSettings
from blackmetal.schemas import DEFAULT_PREFIX, ConfigError, validate_prefix


@dataclass(slots=True)
class FoxgloveSettings:
    prefix: str = setting(DEFAULT_PREFIX, "key-expression prefix of the robot, e.g. fleet/a")
    host: str = setting("127.0.0.1", "address the WebSocket server listens on (0.0.0.0: every interface)", metavar="ADDR")
    port: int = setting(8765, "WebSocket port (0: any free port)", metavar="PORT")
    mcap: str | None = setting(None, "also write the view's channels to this MCAP file", metavar="FILE")
    path_length: int = setting(2000, "poses kept in the driven path", metavar="N")
    call_timeout: float = setting(
        2.0, "seconds a service call (set_estop, reset_odometry) waits for the gateway's or the odometry's confirmation", metavar="S"
    )
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)

    def check(self) -> None:
        validate_prefix(self.prefix)
        if not 0 <= self.port <= 65535:
            raise ConfigError(f"--port must be 0..65535, got {self.port}")
        if self.path_length < 2:
            raise ConfigError(f"--path-length must be at least 2, got {self.path_length}")
        if not 0.1 <= self.call_timeout <= 60.0:
            raise ConfigError(f"--call-timeout must be 0.1..60 s, got {self.call_timeout:g}")
