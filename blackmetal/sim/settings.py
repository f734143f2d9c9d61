"""The simulator's settings: one typed model; its options, help and file names come from these fields."""

from __future__ import annotations

from dataclasses import dataclass, field

import msgspec

from blackmetal import robot_model as model
from blackmetal.runtime.settings import check_positive, setting
from blackmetal.runtime.zenoh_setup import ZenohSettings
from blackmetal.schemas import DEFAULT_PREFIX, ConfigError, SimFaults, validate_prefix

FAULTS = tuple(SimFaults.__struct_fields__)


@dataclass(slots=True)
class SimSettings:
    host: str = setting("127.0.0.1", "address to listen on", metavar="HOST")
    control_port: int = setting(model.CONTROL_PORT, "control port; 0 = a free port", metavar="PORT")
    log_port: int = setting(model.LOG_PORT, "log port; 0 = a free port", metavar="PORT")
    log_interval: float = setting(1.0, "seconds between log-port state reports", metavar="S")
    wheel_separation: float = setting(model.WHEEL_SEPARATION, "the true distance between the wheels, m", metavar="M")
    left_wheel_scale: float = setting(
        1.0, "real travel of the left wheel per reported impulse, relative to the nominal constant", metavar="F"
    )
    right_wheel_scale: float = setting(1.0, "the same for the right wheel", metavar="F")
    accel_limit: float | None = setting(None, "motor acceleration limit, m/s^2 (default none)", metavar="M/S2")
    watchdog: float = setting(model.ROBOT_WATCHDOG_S, "stop after this many seconds without a motion command", metavar="S")
    seed: int | None = setting(None, "random seed for faults", metavar="N")
    truth_hz: float = setting(50.0, "rate of <prefix>/sim/truth", metavar="HZ")
    prefix: str | None = setting(None, f"key prefix (default {DEFAULT_PREFIX}); implies Zenoh")
    use_zenoh: bool = setting(False, "publish the truth on Zenoh with default settings", flag="--zenoh")
    dropout: float = setting(0.0, "fault: per-wheel probability of a stray 0 reading", metavar="P")
    spike: float = setting(0.0, "fault: per-wheel probability of an impossible reading", metavar="P")
    full_buffer: float = setting(0.0, "fault: probability a command is dropped with FULL_BUFFER", metavar="P")
    delay: float = setting(0.0, "fault: delay before every reply, s", metavar="S")
    garbage: float = setting(0.0, "fault: probability of garbage bytes before a reply", metavar="P")
    glue: float = setting(0.0, "fault: probability a reply is glued to the next", metavar="P")
    split: float = setting(0.0, "fault: probability a reply is split across writes", metavar="P")
    disconnect: float = setting(0.0, "fault: probability per request of dropping the connection", metavar="P")
    silent: bool = setting(False, "fault: keep the connections open but never answer")
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)

    def check(self) -> None:
        check_positive(self, "wheel_separation watchdog truth_hz log_interval accel_limit left_wheel_scale right_wheel_scale")
        for name in ("left_wheel_scale", "right_wheel_scale"):
            if not 0.5 <= getattr(self, name) <= 2.0:
                raise ConfigError(f"{name} must be within 0.5..2.0, got {getattr(self, name)}")
        if self.prefix is not None:
            validate_prefix(self.prefix)
        self.faults()

    def faults(self) -> SimFaults:
        try:
            return msgspec.convert({name: getattr(self, name) for name in FAULTS}, SimFaults)
        except msgspec.ValidationError as exc:
            raise ConfigError(f"invalid fault setting: {exc}") from None

    @property
    def uses_zenoh(self) -> bool:
        return self.zenoh.given or self.use_zenoh or self.prefix is not None
