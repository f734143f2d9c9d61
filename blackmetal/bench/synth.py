"""Synthetic impulse logs of known legs, for tests, benchmarks and demos.

Readings are whole impulses per second with the remainder carried (counts are never lost), at
jittered instants, with single-sample dropouts and spikes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from blackmetal import robot_model as model
from blackmetal.robot_model import NOMINAL_ENCODERS, Encoders
from blackmetal.schemas import WheelImpulses


@dataclass(frozen=True, slots=True)
class Leg:
    duration: float
    left: float  # m/s
    right: float  # m/s


def square_legs(side: float = 2.0, speed: float = 0.3, turn_rate: float = 0.8, pause: float = 0.5,
                separation: float = model.WHEEL_SEPARATION, clockwise: bool = False) -> list[Leg]:  # fmt: skip
    """Drive a square: straight, stop, turn 90 degrees in place, stop; four times."""
    rim = turn_rate * separation / 2
    turn = 0.5 * math.pi / turn_rate
    sign = -1.0 if clockwise else 1.0
    legs: list[Leg] = [Leg(pause, 0.0, 0.0)]
    for _ in range(4):
        legs += [Leg(side / speed, speed, speed), Leg(pause, 0.0, 0.0)]
        legs += [Leg(turn, -sign * rim, sign * rim), Leg(pause, 0.0, 0.0)]
    return legs


@dataclass
class SynthLog:
    seq: np.ndarray
    stamp: np.ndarray
    left: np.ndarray
    right: np.ndarray

    def messages(self) -> list[WheelImpulses]:
        return [
            WheelImpulses(seq=int(s), stamp=float(t), left=int(left), right=int(right))
            for s, t, left, right in zip(self.seq, self.stamp, self.left, self.right, strict=False)
        ]

    def jsonl(self) -> bytes:
        return b"".join(
            b'{"seq":%d,"stamp":%r,"left":%d,"right":%d}\n' % (s, float(t), left, right)
            for s, t, left, right in zip(self.seq.tolist(), self.stamp.tolist(), self.left.tolist(), self.right.tolist(), strict=False)
        )

    def __len__(self) -> int:
        return len(self.seq)


def synth_log(
    legs: list[Leg],
    dt_range: tuple[float, float] = (0.005, 0.015),
    dropout: float = 0.0,
    spike: float = 0.0,
    seed: int = 1,
    start: float = 1_795_000_000.0,
    encoders: Encoders = NOMINAL_ENCODERS,
    max_wheel_speed: float = model.MAX_WHEEL_SPEED,
) -> SynthLog:
    """Readings of ``legs`` at jittered instants, with dropouts and spikes injected per wheel."""
    rng = np.random.default_rng(seed)
    total = sum(leg.duration for leg in legs)
    n = int(total / dt_range[0]) + 2
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(*dt_range, n))])
    t = t[t <= total]
    # cumulative rim travel of each wheel is piecewise linear: exact at leg boundaries
    bounds = np.concatenate([[0.0], np.cumsum([leg.duration for leg in legs])])
    travel_l = np.concatenate([[0.0], np.cumsum([leg.left * leg.duration for leg in legs])])
    travel_r = np.concatenate([[0.0], np.cumsum([leg.right * leg.duration for leg in legs])])
    speed_l = np.diff(np.interp(t, bounds, travel_l)) / np.diff(t)  # mean rim speed over each interval
    speed_r = np.diff(np.interp(t, bounds, travel_r)) / np.diff(t)
    readings = []
    for rate in encoders.to_impulses(speed_l, speed_r):  # impulses per second, right mirrored
        whole = np.round(np.cumsum(rate))  # carry the remainder: no count is ever lost
        counts = np.diff(np.concatenate([[0.0], whole]))
        counts[np.abs(rate) < 1e-9] = 0.0  # standing still reads exactly 0
        readings.append(counts.astype(np.int64))
    left, right = readings
    impossible = np.abs(encoders.to_impulses(max_wheel_speed, max_wheel_speed))
    for wheel, limit in zip((left, right), impossible, strict=False):
        moving = wheel != 0
        drop = (rng.random(len(wheel)) < dropout) & moving
        drop[1:] &= ~drop[:-1]  # single-sample dropouts: never two in a row on one wheel
        wheel[drop] = 0
        bad = rng.random(len(wheel)) < spike
        wheel[bad] = (np.sign(wheel[bad]) + (wheel[bad] == 0)) * (limit * rng.uniform(2, 6, bad.sum())).astype(np.int64)
    stamps = start + t[1:]
    return SynthLog(np.arange(len(stamps), dtype=np.int64), stamps, left, right)
