"""The odometry service's settings: one typed model, the same precedence rules as every service."""

from __future__ import annotations

from dataclasses import dataclass, field

from blackmetal import robot_model as model
from blackmetal.robot_model import Encoders
from blackmetal.runtime.settings import setting
from blackmetal.runtime.zenoh_setup import ZenohSettings
from blackmetal.schemas import DEFAULT_PREFIX, ConfigError, validate_prefix

from .errors import OdometryError
from .params import OdometryParams


@dataclass(slots=True)
class PipelineSettings:
    """The pipeline's options, shared by ``blackmetal odometry`` and ``blackmetal replay``."""

    wheel_separation: float = setting(model.WHEEL_SEPARATION, "distance between the wheels, m", metavar="M")
    impulses_left: float = setting(model.IMPULSES_PER_METER_LEFT, "impulses per metre, left wheel", metavar="N")
    impulses_right: float = setting(model.IMPULSES_PER_METER_RIGHT, "impulses per metre, right wheel", metavar="N")
    mirror_right: bool = setting(model.RIGHT_ENCODER_MIRRORED, "the right encoder is not mirrored", flag="--no-mirror-right", const=False)
    max_wheel_speed: float = setting(model.MAX_WHEEL_SPEED, "m/s; readings above 1.05x this are glitches", metavar="M/S")
    filter_alpha: float = setting(0.3, "low-pass strength in [0, 1), 0 = off", metavar="A")
    max_gap: float = setting(0.5, "do not integrate across gaps longer than this, s", metavar="S")

    def params(self) -> OdometryParams:
        return OdometryParams(
            wheel_separation=self.wheel_separation,
            encoders=Encoders(self.impulses_left, self.impulses_right, self.mirror_right),
            max_wheel_speed=self.max_wheel_speed,
            filter_alpha=self.filter_alpha,
            max_gap=self.max_gap,
        )

    def check(self) -> None:
        try:
            self.params().check()
        except OdometryError as exc:
            raise ConfigError(str(exc)) from None


@dataclass(slots=True)
class OdometrySettings(PipelineSettings):
    prefix: str = setting(DEFAULT_PREFIX, "key-expression prefix, e.g. fleet/a")
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)

    def check(self) -> None:
        PipelineSettings.check(self)
        validate_prefix(self.prefix)
