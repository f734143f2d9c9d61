"""The odometry's constants: one frozen record shared by the streaming, batch and calibration paths."""

from __future__ import annotations

from dataclasses import dataclass

from blackmetal import robot_model as model
from blackmetal.robot_model import NOMINAL_ENCODERS, Encoders

from .errors import OdometryError


@dataclass(frozen=True, slots=True)
class OdometryParams:
    wheel_separation: float = model.WHEEL_SEPARATION
    encoders: Encoders = NOMINAL_ENCODERS
    max_wheel_speed: float = model.MAX_WHEEL_SPEED
    #: A reading above ``max_wheel_speed * spike_factor`` is a glitch (margin for quantisation).
    spike_factor: float = 1.05
    filter_alpha: float = 0.3  # low-pass strength a in [0, 1): 0 = off
    max_gap: float = 0.5  # s; samples further apart are not integrated across

    def check(self) -> None:
        if not 0.0 <= self.filter_alpha < 1.0:
            raise OdometryError(f"filter_alpha must be in [0, 1), got {self.filter_alpha}")
        values = {
            "wheel_separation": self.wheel_separation,
            "impulses_left": self.encoders.impulses_per_meter_left,
            "impulses_right": self.encoders.impulses_per_meter_right,
            "max_wheel_speed": self.max_wheel_speed,
            "max_gap": self.max_gap,
        }
        for name, value in values.items():
            if not value > 0:
                raise OdometryError(f"{name} must be positive, got {value}")
        if self.spike_factor < 1.0:
            raise OdometryError("spike_factor must be >= 1")

    @property
    def spike_limit(self) -> float:
        return self.max_wheel_speed * self.spike_factor
