"""The streaming odometry: from raw wheel impulses to a pose, one sample at a time. Pure and clock-free.

Pipeline per sample (each reading describes the interval since the previous one):

1. convert impulses/s to rim speed in m/s (right encoder mirrored);
2. glitches: a reading above the maximum wheel speed is a sensor fault and
   is replaced by the wheel's previous reading; a single 0 in motion is held
   at the previous output (a dropout); a second 0 shows the first was a real
   stop, so the step integrated with the held value is taken back;
3. the original first-order low-pass ``y = a*y + (1-a)*x``, reset to the
   first non-zero sample after a stop (no ramp from rest), ``a = 0`` = off;
   it smooths the published velocity ``v``/``w``;
4. exact-arc integration of the cleaned speeds (before the low-pass: a
   filter with unit gain that is reset at every start integrates to
   ``a/(1-a)*dt*(first - last)`` too much or too little per run, measured
   at 18 mrad over four turns of a square) over the real time between the
   samples' stamps; a gap longer than ``max_gap`` is not integrated (reported
   instead), nor is the jump to a restarted gateway's new sequence.

Step 2 and 3 are :mod:`blackmetal.odometry_service.glitches`; which samples are
integrated, and over which interval, is :mod:`blackmetal.odometry_service.sample_order`.

:mod:`blackmetal.odometry_service.batch` implements the same pipeline with numpy for
replays; the two agree to 1e-9.
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
    samples: int = 0
    retractions: int = 0
    events: list[str] = field(default_factory=list)  # report texts of accepted samples, drained by OdometryCore
    _glitches: Glitches = field(init=False)
    _tally: EpochTally = field(init=False, default_factory=EpochTally)
    _order: SampleOrder = field(init=False)
    _before_last: tuple[float, float, float] | None = None  # pose before the last step
    _last_step: tuple[float, float, float] | None = None  # (left, right, dt) of the last step

    def __post_init__(self) -> None:
        self._glitches = Glitches(self.params.filter_alpha, self.params.spike_limit)
        self._order = SampleOrder(self.params.max_gap, live=self.live)

    @property
    def spikes(self) -> int:
        return self._glitches.spikes

    @property
    def dropouts(self) -> int:
        return self._glitches.dropouts

    @property
    def gaps(self) -> int:
        return self._tally.gaps

    @property
    def restarts(self) -> int:
        return self._tally.restarts

    @property
    def missed(self) -> int:
        return self._tally.missed

    def reset(self, x: float = 0.0, y: float = 0.0, yaw: float = 0.0) -> Pose:
        """Start over at the given pose: every piece of state is cleared, the next sample starts a new epoch.

        Raises OdometryError for a pose that is not finite or is absurd (beyond
        RESET_LIMIT_M from the origin, or a yaw beyond RESET_LIMIT_RAD), naming it.
        """
        for name, value, limit in (("x", x, RESET_LIMIT_M), ("y", y, RESET_LIMIT_M), ("yaw", yaw, RESET_LIMIT_RAD)):
            if not math.isfinite(value) or abs(value) > limit:
                raise OdometryError(f"reset refused: {name} = {value!r} is not a pose (|{name}| must be at most {limit:g})")
        self.x, self.y, self.yaw = x, y, wrap_angle(yaw)
        self.v = self.w = 0.0
        self._before_last = self._last_step = None
        self._glitches.reset()
        self._order.forget()
        return self.pose()

    def pose(self) -> Pose:
        return make_pose(self.stamp, self.x, self.y, self.yaw, self.v, self.w)

    def feed(self, sample: WheelImpulses, arrival: float | None = None) -> Pose:
        """One impulse sample in, the updated pose out. Raises SampleRejected for unusable samples.

        ``arrival``: when the sample arrived, on the receiver's monotonic clock (None in replays;
        required when ``live``, where a sample without ``mono`` or ``source`` raises UnstampedSample).
        """
        verdict = self._order.check(sample.seq, sample.stamp, sample.mono, sample.source, arrival)
        new_epoch, dt = verdict.new_epoch, verdict.dt
        self._tally.count(verdict)
        if verdict.event is not None:
            self.events.append(verdict.event)
        p = self.params
        raw_left, raw_right = p.encoders.to_speeds(float(sample.left), float(sample.right))
        if new_epoch:
            self._glitches.reset()
            self._before_last = self._last_step = None
        update = self._glitches.update(raw_left, raw_right)
        u_left, u_right, fix_left, fix_right = update.left, update.right, update.revise_left, update.revise_right
        if (fix_left is not None or fix_right is not None) and self._before_last is not None and self._last_step is not None:
            # the previous step used a provisional value that the next sample proved wrong: redo it
            self.retractions += 1
            last_left, last_right, last_dt = self._last_step
            if fix_left is not None:
                last_left = fix_left
            if fix_right is not None:
                last_right = fix_right
            bx, by, byaw = self._before_last
            self.x, self.y, self.yaw = arc_step(bx, by, byaw, last_left * last_dt, last_right * last_dt, p.wheel_separation)
        if not new_epoch:
            self._before_last = (self.x, self.y, self.yaw)
            self._last_step = (u_left, u_right, dt)
            self.x, self.y, self.yaw = arc_step(self.x, self.y, self.yaw, u_left * dt, u_right * dt, p.wheel_separation)
        self.stamp = sample.stamp
        self.v, self.w = wheels_to_twist(update.filtered_left, update.filtered_right, p.wheel_separation)
        self.samples += 1
        return self.pose()
