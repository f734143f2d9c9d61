"""Differential-drive physics and command handling of the simulated robot. Pure and clock-injected (``now``).

Wheel speeds are constant between events, so one exact-arc step per interval is exact; while a wheel
accelerates or runs a position move, steps are at most ``substep`` long.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass
from typing import Any

from blackmetal import robot_model as model
from blackmetal import wire
from blackmetal.robot_model import NOMINAL_ENCODERS, UNITY_GAIN, Encoders, WheelGain, arc_step, wheels_to_twist
from blackmetal.schemas import Pose, SimFaults, make_pose
from blackmetal.wire import CommandCode, Request


@dataclass(frozen=True, slots=True)
class RobotParams:
    wheel_separation: float = model.WHEEL_SEPARATION
    encoders: Encoders = NOMINAL_ENCODERS  # the true ones, which the gateway and odometry may not know
    #: Real travel per impulse over the nominal constant (the firmware uses the nominal ones): a wheel with scale
    #: 1.015 runs 1.5 % faster than commanded and reports the commanded impulses. Use :meth:`with_wheel_scales`.
    wheel_scale: WheelGain = UNITY_GAIN

    @classmethod
    def with_wheel_scales(cls, *, left: float, right: float, **others: Any) -> "RobotParams":
        """A robot whose wheels are not their drawing: true encoders follow from the scales."""
        encoders = Encoders(model.IMPULSES_PER_METER_LEFT / left, model.IMPULSES_PER_METER_RIGHT / right)
        return cls(encoders=encoders, wheel_scale=WheelGain(left=left, right=right), **others)

    max_wheel_speed: float = model.MAX_WHEEL_SPEED
    accel_limit: float | None = None  # per wheel, m/s^2; None = wheels follow at once
    watchdog: float = model.ROBOT_WATCHDOG_S  # s without a motion command before it stops by itself
    position_speed: float = 0.3  # rim speed of SET_LR_WHEEL_POSITION moves, m/s
    substep: float = 0.001  # longest integration step while a wheel accelerates or runs a position move, s


class SimRobot:
    def __init__(self, params: RobotParams | None = None, now: float = 0.0, seed: int | None = None) -> None:
        self.params = params or RobotParams()
        self.faults = SimFaults()
        self.rng = random.Random(seed)
        self.t = now
        self.x = self.y = self.yaw = 0.0  # yaw unwrapped internally
        self.speed_left = self.speed_right = 0.0  # actual rim speeds (m/s)
        self.target_left = self.target_right = 0.0  # commanded rim speeds (m/s)
        self.travel_left = self.travel_right = 0.0  # cumulative rim travel (m)
        self._position_left: float | None = None  # remaining travel of a position move (m)
        self._position_right: float | None = None
        self._deadline: float | None = None  # watchdog: stop at this time unless commanded again
        self._carry_left = self._carry_right = 0.0  # encoder quantisation carried between readings
        self._read_at: float | None = None  # time of the previous speed reading
        self._read_travel = (0.0, 0.0)  # rim travel at the previous speed reading
        self._dropped = [False, False]  # the previous reading of each wheel was a dropout
        names = "requests velocity_commands position_commands prepare emergency_stops normal_stops watchdog_stops full_buffer polls position_polls"
        self.counters: dict[str, int] = dict.fromkeys(names.split(), 0)

    @property
    def moving(self) -> bool:
        return self.speed_left != 0.0 or self.speed_right != 0.0 or self._position_left is not None

    def _transient(self) -> bool:
        if self._position_left is not None:
            return True
        return self.params.accel_limit is not None and (self.speed_left != self.target_left or self.speed_right != self.target_right)

    def advance(self, now: float) -> None:
        """Integrate the true pose up to ``now``; fire the watchdog on the way."""
        while True:
            if self._deadline is not None and self.t >= self._deadline:
                self.counters["watchdog_stops"] += 1
                self._halt(immediate=False)
            if self.t >= now:
                return
            t_end = now
            if self._deadline is not None:
                t_end = min(t_end, self._deadline)
            if self._transient():
                t_end = min(t_end, self.t + self.params.substep)
            self._step(t_end - self.t)
            self.t = t_end

    def _step(self, dt: float) -> None:
        if self._position_left is not None and self._position_right is not None:
            d_left, self._position_left, self.speed_left = self._position_move(self._position_left, dt)
            d_right, self._position_right, self.speed_right = self._position_move(self._position_right, dt)
            if self._position_left == 0.0 and self._position_right == 0.0:
                self._position_left = self._position_right = None
        else:
            d_left, self.speed_left = self._ramp(self.speed_left, self.target_left, dt)
            d_right, self.speed_right = self._ramp(self.speed_right, self.target_right, dt)
        if d_left == 0.0 and d_right == 0.0:
            return  # standing: the pose and the travel stay (a fleet's robots mostly stand, stepped 150 times a second)
        self.x, self.y, self.yaw = arc_step(self.x, self.y, self.yaw, d_left, d_right, self.params.wheel_separation)
        self.travel_left += d_left
        self.travel_right += d_right

    def _ramp(self, speed: float, target: float, dt: float) -> tuple[float, float]:
        """Travel over ``dt`` and the speed at its end, under the acceleration limit."""
        accel = self.params.accel_limit
        if accel is None or speed == target:
            return target * dt, target
        change = target - speed
        t_reach = abs(change) / accel
        if t_reach >= dt:
            end = speed + math.copysign(accel * dt, change)
            return 0.5 * (speed + end) * dt, end
        return 0.5 * (speed + target) * t_reach + target * (dt - t_reach), target

    def _position_move(self, remaining: float, dt: float) -> tuple[float, float, float]:
        """Travel, remaining travel and speed of one wheel in a position move."""
        step = self.params.position_speed * dt
        if abs(remaining) <= step:
            return remaining, 0.0, 0.0
        sign = math.copysign(1.0, remaining)
        return sign * step, remaining - sign * step, sign * self.params.position_speed

    def _halt(self, immediate: bool) -> None:
        self._deadline = None
        self.target_left = self.target_right = 0.0
        self._position_left = self._position_right = None
        if immediate or self.params.accel_limit is None:
            self.speed_left = self.speed_right = 0.0

    def pose(self, stamp: float) -> Pose:
        v, w = wheels_to_twist(self.speed_left, self.speed_right, self.params.wheel_separation)
        return make_pose(stamp, self.x, self.y, self.yaw, v=v, w=w)

    def read_impulses(self, now: float | None = None) -> tuple[int, int]:
        """Impulses per second as reported (right mirrored), with faults: the mean rate since the previous reading
        (the current rate for the first, or after over a second), whole, the remainder carried to the next."""
        now = self.t if now is None else now
        self.advance(now)
        interval = now - self._read_at if self._read_at is not None else 0.0
        if 0.0 < interval <= 1.0:
            rate_left = (self.travel_left - self._read_travel[0]) / interval
            rate_right = (self.travel_right - self._read_travel[1]) / interval
        else:
            rate_left, rate_right = self.speed_left, self.speed_right
        self._read_at = now
        self._read_travel = (self.travel_left, self.travel_right)
        exact_left, exact_right = self.params.encoders.to_impulses(rate_left, rate_right)
        left, self._carry_left = self._quantise(exact_left, self._carry_left)
        right, self._carry_right = self._quantise(exact_right, self._carry_right)
        return self._sensor_fault(left, 0), self._sensor_fault(right, 1)

    @staticmethod
    def _quantise(rate: float, carry: float) -> tuple[int, float]:
        if abs(rate) < 1e-9:
            return 0, 0.0
        value = rate + carry
        whole = round(value)
        return whole, value - whole

    def _sensor_fault(self, value: int, wheel: int) -> int:
        """Single-sample dropouts (never two in a row) and impossible spikes."""
        faults = self.faults
        dropped = self._dropped[wheel]
        self._dropped[wheel] = False
        if faults.dropout and value != 0 and not dropped and self.rng.random() < faults.dropout:
            self._dropped[wheel] = True
            return 0
        if faults.spike and self.rng.random() < faults.spike:
            limit = self.params.max_wheel_speed
            impossible = abs(self.params.encoders.to_impulses(limit, limit)[wheel]) * self.rng.uniform(2.0, 6.0)
            return int(math.copysign(impossible, value or 1))
        return value

    def read_positions(self) -> tuple[int, int]:
        left, right = self.params.encoders.to_impulses(self.travel_left, self.travel_right)
        return round(left), round(right)

    def handle(self, request: Request, now: float) -> list[bytes]:
        """The robot's replies to one command at ``now``."""
        self.advance(now)
        self.counters["requests"] += 1
        if self.faults.full_buffer and self.rng.random() < self.faults.full_buffer:
            self.counters["full_buffer"] += 1
            return [wire.encode_status(wire.STATUS_FULL_BUFFER)]
        command = request.command
        replies = [wire.encode_status(wire.STATUS_OK)]
        separator = " " if self.rng.random() < 0.5 else ","
        if command is CommandCode.EMG_STOP:
            self.counters["emergency_stops"] += 1
            self._halt(immediate=True)
        elif command is CommandCode.NORMAL_STOP:
            self.counters["normal_stops"] += 1
            self._halt(immediate=False)
        elif command is CommandCode.SET_LR_WHEEL_VELOCITY:
            self.counters["velocity_commands"] += 1
            limit = self.params.max_wheel_speed
            self._position_left = self._position_right = None
            scale = self.params.wheel_scale
            self.target_left = max(-limit, min(limit, float(request.left or 0.0))) * scale.left
            self.target_right = max(-limit, min(limit, float(request.right or 0.0))) * scale.right
            if self.params.accel_limit is None:
                self.speed_left, self.speed_right = self.target_left, self.target_right
            self._deadline = now + self.params.watchdog
        elif command is CommandCode.SET_LR_WHEEL_POSITION:
            # relative travel per wheel, natural sign, at position_speed; what drops it: docs/safety.md "Position moves"
            self.counters["position_commands"] += 1
            self._position_left, self._position_right = self.params.encoders.commanded_travel(
                int(request.left or 0), int(request.right or 0)
            )
            self.target_left = self.target_right = 0.0
            self._deadline = now + self.params.watchdog
        elif command is CommandCode.PREPARE_WHEEL_CONTROLLER:
            self.counters["prepare"] += 1
        elif command is CommandCode.GET_LR_WHEEL_VELOCITY:
            self.counters["polls"] += 1
            left, right = self.read_impulses(now)
            replies.append(wire.encode_wheel_speeds(left=left, right=right, separator=separator))
        elif command is CommandCode.GET_LR_WHEEL_POSITION:
            self.counters["position_polls"] += 1
            left, right = self.read_positions()
            replies.append(wire.encode_wheel_positions(left=left, right=right, separator=separator))
        return replies
