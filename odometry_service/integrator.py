"""The streaming odometry: raw wheel impulses to a pose, one sample at a time. Pure and clock-free.

The pipeline is docs/commands/odometry.md; glitches and the low-pass are :mod:`.glitches`, which samples
are integrated over which interval :mod:`.sample_order`; :mod:`.batch` is the same in numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from blackmetal.robot_model import arc_step, wheels_to_twist
from blackmetal.schemas import Pose, WheelImpulses, make_pose, wrap_angle

from .errors import OdometryError
from .glitches import Glitches
from .params import OdometryParams
from .sample_order import EpochTally, SampleOrder

#: A reset to a pose further than this from the origin (m), or a yaw beyond this (rad), is refused as absurd.
RESET_LIMIT_M = 1e6
RESET_LIMIT_RAD = 1e3


@dataclass(slots=True)
class Odometry:
    """Streaming odometry: :meth:`feed` one WheelImpulses, get the pose after it."""

    params: OdometryParams = field(default_factory=OdometryParams)
    #: Live input (the service): every sample needs ``mono``, ``source`` and ``arrival``; False: a log, which may lack them.
    live: bool = field(default=False, kw_only=True)
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0  # unwrapped
    v: float = 0.0
    w: float = 0.0
    stamp: float = 0.0
    retractions: int = 0
    events: list[str] = field(default_factory=list)  # report texts of accepted samples, drained by OdometryCore
    glitches: Glitches = field(init=False)
    tally: EpochTally = field(init=False, default_factory=EpochTally)
    _order: SampleOrder = field(init=False)
    _before_last: tuple[float, float, float] | None = None  # pose before the last step
    _last_step: tuple[float, float, float] | None = None  # (left, right, dt) of the last step

    def __post_init__(self) -> None:
        self.glitches = Glitches(self.params.filter_alpha, self.params.spike_limit)
        self._order = SampleOrder(self.params.max_gap, live=self.live)

    def reset(self, x: float = 0.0, y: float = 0.0, yaw: float = 0.0) -> Pose:
        """Start over at the given pose, every state cleared; OdometryError names a pose not finite or beyond the limits."""
        for name, value, limit in (("x", x, RESET_LIMIT_M), ("y", y, RESET_LIMIT_M), ("yaw", yaw, RESET_LIMIT_RAD)):
            if not math.isfinite(value) or abs(value) > limit:
                raise OdometryError(f"reset refused: {name} = {value!r} is not a pose (|{name}| must be at most {limit:g})")
        self.x, self.y, self.yaw = x, y, wrap_angle(yaw)
        self.v = self.w = 0.0
        self._before_last = self._last_step = None
        self.glitches.reset()
        self._order.forget()
        return self.pose()

    def pose(self) -> Pose:
        return make_pose(self.stamp, self.x, self.y, self.yaw, self.v, self.w)

    def feed(self, sample: WheelImpulses, arrival: float | None = None) -> Pose:
        """The pose after one sample; SampleRejected for unusable ones. ``arrival``: the receiver's monotonic time, if live."""
        verdict = self._order.check(sample.seq, sample.stamp, sample.mono, sample.source, arrival)
        new_epoch, dt = verdict.new_epoch, verdict.dt
        self.tally.count(verdict)
        if verdict.event is not None:
            self.events.append(verdict.event)
        p = self.params
        raw_left, raw_right = p.encoders.to_speeds(float(sample.left), float(sample.right))
        if new_epoch:
            self.glitches.reset()
            self._before_last = self._last_step = None
        update = self.glitches.update(raw_left, raw_right)
        u_left, u_right, fix_left, fix_right = update.left, update.right, update.revise_left, update.revise_right
        if (fix_left is not None or fix_right is not None) and self._before_last is not None and self._last_step is not None:
            # the previous step used a provisional value that the next sample proved wrong: redo it
            self.retractions += 1
            last_left, last_right, last_dt = self._last_step
            last_left = last_left if fix_left is None else fix_left
            last_right = last_right if fix_right is None else fix_right
            bx, by, byaw = self._before_last
            self.x, self.y, self.yaw = arc_step(bx, by, byaw, last_left * last_dt, last_right * last_dt, p.wheel_separation)
        if not new_epoch:
            self._before_last = (self.x, self.y, self.yaw)
            self._last_step = (u_left, u_right, dt)
            self.x, self.y, self.yaw = arc_step(self.x, self.y, self.yaw, u_left * dt, u_right * dt, p.wheel_separation)
        self.stamp = sample.stamp
        self.v, self.w = wheels_to_twist(update.filtered_left, update.filtered_right, p.wheel_separation)
        return self.pose()
