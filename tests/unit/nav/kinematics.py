"""A simulated differential drive for the navigation's tests: what a command meets between the controller and the floor.

Written apart from the controller (no code shared with it), so a test holds the controller to an independent model:
the command computed on a pose reaches the wheels ``delay`` periods later, through an acceleration limiter like the
gateway's governor (each component approaches its target by at most ``accel * dt`` a period), and the body moves as a
unicycle, integrated in small steps.
"""

from __future__ import annotations

import math
import random
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

PERIOD = 0.02  # the odometry's poses at the gateway's 50 Hz poll


@dataclass
class Robot:
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    #: Periods between a command computed on a pose and the wheels running it.
    delay: int = 1
    #: The gateway's acceleration limits (m/s^2, rad/s^2); None: none.
    linear_accel: float | None = 0.5
    angular_accel: float | None = 2.0
    dt: float = PERIOD
    #: Pose noise: uniform within this many metres (x, y) and radians (yaw), as the odometry's quantisation.
    noise: float = 0.0
    yaw_noise: float = 0.0
    seed: int = 0
    v: float = 0.0
    w: float = 0.0
    _queue: deque[tuple[float, float]] = field(default_factory=deque)
    _rng: random.Random = field(default_factory=random.Random)

    def __post_init__(self) -> None:
        self._queue.extend([(0.0, 0.0)] * self.delay)
        self._rng.seed(self.seed)

    def pose(self) -> tuple[float, float, float]:
        """What the odometry reports (yaw wrapped)."""
        n, m, rng = self.noise, self.yaw_noise, self._rng
        return self.x + rng.uniform(-n, n), self.y + rng.uniform(-n, n), math.remainder(self.yaw + rng.uniform(-m, m), math.tau)

    def run(self, v: float, w: float) -> None:
        """The command computed on the last pose; one period passes."""
        self._queue.append((v, w))
        target_v, target_w = self._queue.popleft()
        self.v = _approach(self.v, target_v, self.linear_accel, self.dt)
        self.w = _approach(self.w, target_w, self.angular_accel, self.dt)
        steps = 10
        h = self.dt / steps
        for _ in range(steps):
            mid = self.yaw + self.w * h / 2
            self.x += self.v * h * math.cos(mid)
            self.y += self.v * h * math.sin(mid)
            self.yaw += self.w * h


def _approach(current: float, target: float, accel: float | None, dt: float) -> float:
    if accel is None:
        return target
    return min(max(target, current - accel * dt), current + accel * dt)


def drive(step: Callable[[float, float, float], tuple[float, float] | None], robot: Robot, timeout: float = 120.0) -> float:
    """Feed ``step`` a pose per period until it returns None (done); the time that took."""
    t = 0.0
    while t < timeout:
        command = step(*robot.pose())
        if command is None:
            return t
        robot.run(*command)
        t += robot.dt
    return math.inf
