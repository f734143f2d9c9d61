"""From raw wheel impulses to a pose, one sample at a time. Pure and clock-free.

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

:mod:`odometry_service.batch` implements the same pipeline with numpy for
replays; the two agree to 1e-9.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from blackmetal import robot_model as model
from blackmetal.robot_model import NOMINAL_ENCODERS, Encoders, arc_step, wheels_to_twist
from schemas import Pose, WheelImpulses, make_pose, wrap_angle

from .errors import OdometryError, SampleRejected

#: A reset to a pose further than this from the origin (m), or a yaw beyond this (rad), is refused as absurd.
RESET_LIMIT_M = 1e6
RESET_LIMIT_RAD = 1e3


@dataclass(frozen=True, slots=True)
class OdometryParams:
    wheel_separation: float = model.WHEEL_SEPARATION
    #: Impulses per metre of each wheel and the right encoder's mirroring.
    encoders: Encoders = NOMINAL_ENCODERS
    max_wheel_speed: float = model.MAX_WHEEL_SPEED
    #: A reading above ``max_wheel_speed * spike_factor`` is a glitch (margin for quantisation).
    spike_factor: float = 1.05
    #: Low-pass strength a in [0, 1): 0 = off.
    filter_alpha: float = 0.3
    #: Samples further apart than this (s) are not integrated across.
    max_gap: float = 0.5

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


@dataclass(slots=True)
class WheelState:
    """What the glitch rules and the low-pass remember of one wheel."""

    y: float = 0.0  # filter output (m/s)
    prev: float = 0.0  # cleaned reading of the previous sample
    prev2: float = 0.0  # ... and of the one before
    zero_run: int = 2  # consecutive zeros after the previous sample, capped at 2; 2 = at rest
    raw_prev: float = 0.0  # raw reading of the previous sample (spikes included)
    anchor: float = 0.0  # last trustworthy raw reading (not a spike, not a first zero)
    anchor_other: float = 0.0  # the other wheel's raw reading at that sample
    anchor_other_ok: bool = False  # ... and whether it was trustworthy (not a spike)

    def reset(self) -> None:
        self.y = self.prev = self.prev2 = self.raw_prev = self.anchor = self.anchor_other = 0.0
        self.zero_run = 2
        self.anchor_other_ok = False


@dataclass(frozen=True, slots=True)
class Update:
    """What one sample gives: rim speeds to integrate over its interval, the low-passed
    speeds (published as v and w), and revised speeds for the previous interval (None = keep)."""

    left: float
    right: float
    filtered_left: float
    filtered_right: float
    revise_left: float | None
    revise_right: float | None


class Glitches:
    """Spike, dropout and stop rules for both wheels, with the low-pass; sample by sample.

    A single zero while both wheels move is a dropout: it is estimated from
    the wheel's previous reading scaled by how the other wheel changed (the
    curvature is kept), or held when the other wheel cannot tell. The next
    sample settles it, and the previous step is revised when it was wrong:

    * a second zero means the wheel really stopped, unless the other wheel
      was still moving at the first zero and stops only now (a dropout at a
      joint stop): the step is redone with the wheel at 0;
    * a wheel that reads 0 on the first sample of a joint start (the other
      wheel starts on it) and moves on the next had its start dropped: the
      step is redone with an estimate from the next reading.
    """

    def __init__(self, alpha: float, spike_limit: float) -> None:
        self.alpha = alpha
        self.limit = spike_limit
        self.left = WheelState()
        self.right = WheelState()
        self.spikes = 0
        self.dropouts = 0
        self.started = False  # a previous sample exists in this epoch
        self.started2 = False  # two previous samples exist in this epoch

    def reset(self) -> None:
        self.left.reset()
        self.right.reset()
        self.started = self.started2 = False

    def _clip(self, value: float) -> float:
        return max(-self.limit, min(self.limit, value))

    def update(self, raw_left: float, raw_right: float) -> "Update":
        """One reading of both wheels in; speeds to integrate, filtered speeds, revisions out."""
        wheels = (self.left, self.right)
        raws = (raw_left, raw_right)
        valid = (abs(raw_left) <= self.limit, abs(raw_right) <= self.limit)
        clean = []
        for i, state in enumerate(wheels):
            raw, raw_other = raws[i], raws[1 - i]
            if valid[i]:
                clean.append(raw)
                continue
            # a spike: the last trustworthy reading, scaled by how the other wheel changed since
            self.spikes += 1
            value = state.anchor
            if valid[1 - i] and state.anchor_other_ok and raw_other != 0.0 and state.anchor_other != 0.0:
                value = self._clip(value * raw_other / state.anchor_other)
            clean.append(value)
        revisions: list[float | None] = [None, None]
        speeds = []
        outputs = []
        for i, (me, other) in enumerate(((self.left, self.right), (self.right, self.left))):
            x, x_other = clean[i], clean[1 - i]
            if self.started2:
                if x == 0.0 and me.zero_run == 1 and not (other.prev != 0.0 and x_other == 0.0):
                    revisions[i] = 0.0  # the estimated zero was a real stop
                    self.dropouts -= 1
                elif x != 0.0 and me.zero_run >= 2 and other.prev2 == 0.0 and other.prev != 0.0 and x_other != 0.0:
                    revisions[i] = self._clip(x * other.prev / x_other)  # the start of a joint start was dropped
            zero_run = me.zero_run
            if x == 0.0 and zero_run == 0:
                # a first zero in motion: a dropout until the next sample says otherwise
                self.dropouts += 1
                if other.prev != 0.0 and x_other != 0.0:
                    u = self._clip(me.prev * x_other / other.prev)  # keep the curvature
                else:
                    u = me.prev  # hold
                me.zero_run = 1
            elif x == 0.0:
                u = 0.0
                me.zero_run = 2
            else:
                u = x
                me.zero_run = 0
            if u == 0.0:
                me.y = 0.0
            elif zero_run >= 2:
                me.y = u  # from rest: no slow ramp
            else:
                me.y = self.alpha * me.y + (1.0 - self.alpha) * u
            speeds.append(u)
            outputs.append(me.y)
        for i, state in enumerate(wheels):
            raw = raws[i]
            if valid[i] and not (raw == 0.0 and state.raw_prev != 0.0):
                state.anchor, state.anchor_other, state.anchor_other_ok = raw, raws[1 - i], valid[1 - i]
            state.raw_prev = raw
            state.prev2, state.prev = state.prev, clean[i]
        self.started2 = self.started
        self.started = True
        return Update(speeds[0], speeds[1], outputs[0], outputs[1], revisions[0], revisions[1])


@dataclass(frozen=True, slots=True)
class Verdict:
    """What :class:`SampleOrder` decided about one sample."""

    new_epoch: bool  # do not integrate from the previous sample
    dt: float  # seconds since the previous sample (0 for a new epoch)
    event: str | None = None  # worth reporting, though accepted


#: Samples may claim at most this much more time than their arrivals show, in total over an epoch (s).
SPACING_TOLERANCE_S = 0.1
#: How far the receiver's estimate of the smallest delivery delay may settle below the first sample's (s).
SETTLE_S = 0.5
#: Impulses from another gateway are taken over only after the followed one was silent this long (s).
FOLLOW_TIMEOUT_S = 1.0


@dataclass(slots=True)
class SampleOrder:
    """Which impulse samples may be integrated, and over which interval: one rule set for live odometry and replay.

    The interval is the gateway's monotonic time (``mono``) when the sample
    carries it, so a wall-clock step (NTP) or a stamp from the future cannot
    freeze or stretch the pose; older logs without it use the wall stamps.
    A sample is rejected (:class:`SampleRejected`, with the reason) when it
    repeats or goes back in sequence from the same gateway, goes back in
    time, claims more time than its arrival shows, or comes from another
    gateway while the followed one is alive. A gateway that restarts (new
    ``source``) or a gap longer than ``max_gap`` starts a new epoch.

    The arrival check is cumulative, so delivery jitter on a loaded machine
    cannot trip it: ``arrival - mono`` (``arrival`` on the receiver's
    monotonic clock; replay has none) is the delivery delay plus a constant
    and never falls below its smallest value, unless samples claim time that
    did not pass; one that falls more than SPACING_TOLERANCE_S below is rejected.
    """

    max_gap: float
    seq: int | None = None
    time: float | None = None
    source: str | None = None
    arrival: float | None = None
    #: arrival - time of this epoch's first sample, and the smallest since (delivery delay plus a constant).
    first_offset: float | None = None
    least_offset: float | None = None

    def check(self, seq: int, stamp: float, mono: float | None, source: str | None, arrival: float | None) -> Verdict:
        """Accept (and remember) the sample, or raise SampleRejected and remember nothing."""
        time = stamp if mono is None else mono
        if mono is None:
            arrival = None  # wall stamps may step: arrivals are compared with the gateway's monotonic time only
        if self.seq is None or self.time is None:
            return self._accept(seq, time, source, arrival, Verdict(True, 0.0))
        if source != self.source:
            silent = arrival is None or self.arrival is None or arrival - self.arrival >= FOLLOW_TIMEOUT_S
            if not silent:
                raise SampleRejected(
                    f"impulses from gateway {source} while following gateway {self.source}: "
                    "two gateways publish on this prefix; only one is integrated"
                )
            if source is not None and self.source is not None:
                event = f"gateway {source} took over from gateway {self.source} (a restart): not integrating across it"
                return self._accept(seq, time, source, arrival, Verdict(True, 0.0, event))
        if seq <= self.seq:
            if source is None and time > self.time:  # a log without sources: a later stamp means a restart
                event = f"sequence restarted at {seq} after {self.seq} (gateway restart): not integrating across it"
                return self._accept(seq, time, source, arrival, Verdict(True, 0.0, event))
            raise SampleRejected(f"duplicate or out-of-order sample: seq {seq} after seq {self.seq} from the same gateway")
        if time < self.time:
            clock = "stamp" if mono is None else "monotonic time"
            raise SampleRejected(f"{clock} went backwards: seq {seq} at {time:.6f} after seq {self.seq} at {self.time:.6f}")
        dt = time - self.time
        if arrival is not None and self.least_offset is not None and arrival - time < self.least_offset - SPACING_TOLERANCE_S:
            ahead = self.least_offset - (arrival - time)
            raise SampleRejected(
                f"seq {seq} claims {dt:.3f} s since the previous sample, {ahead:.3f} s more than the samples' arrivals allow"
            )
        if dt > self.max_gap:
            event = f"gap of {dt:.3f} s before seq {seq} exceeds {self.max_gap} s: not integrated"
            return self._accept(seq, time, source, arrival, Verdict(True, 0.0, event))
        return self._accept(seq, time, source, arrival, Verdict(False, dt))

    def _accept(self, seq: int, time: float, source: str | None, arrival: float | None, verdict: Verdict) -> Verdict:
        self.seq, self.time, self.source, self.arrival = seq, time, source, arrival
        if arrival is None:
            self.first_offset = self.least_offset = None
        elif verdict.new_epoch or self.first_offset is None or self.least_offset is None:
            self.first_offset = self.least_offset = arrival - time
        else:  # the smallest delivery delay seen, allowed to settle at most SETTLE_S below the first sample's
            self.least_offset = max(min(self.least_offset, arrival - time), self.first_offset - SETTLE_S)
        return verdict

    def forget(self) -> None:
        self.seq = self.time = self.source = self.arrival = self.first_offset = self.least_offset = None


@dataclass(slots=True)
class Odometry:
    """Streaming odometry: :meth:`feed` one WheelImpulses, get the pose after it."""

    params: OdometryParams = field(default_factory=OdometryParams)
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0  # unwrapped
    v: float = 0.0
    w: float = 0.0
    stamp: float = 0.0
    samples: int = 0
    gaps: int = 0
    restarts: int = 0
    missed: int = 0
    retractions: int = 0
    events: list[str] = field(default_factory=list)  # things worth reporting, drained by the service
    _glitches: Glitches = field(init=False)
    _order: SampleOrder = field(init=False)
    _before_last: tuple[float, float, float] | None = None  # pose before the last step
    _last_step: tuple[float, float, float] | None = None  # (left, right, dt) of the last step

    def __post_init__(self) -> None:
        self._glitches = Glitches(self.params.filter_alpha, self.params.spike_limit)
        self._order = SampleOrder(self.params.max_gap)

    @property
    def spikes(self) -> int:
        return self._glitches.spikes

    @property
    def dropouts(self) -> int:
        return self._glitches.dropouts

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

        ``arrival``: when the sample arrived, on the receiver's monotonic clock (None in replays).
        """
        previous_seq = self._order.seq
        verdict = self._order.check(sample.seq, sample.stamp, sample.mono, sample.source, arrival)
        new_epoch, dt = verdict.new_epoch, verdict.dt
        restart = verdict.event is not None and "gap" not in verdict.event
        if verdict.event is not None:
            self.events.append(verdict.event)
            self.restarts += restart
            self.gaps += not restart
        if previous_seq is not None and not restart and sample.seq > previous_seq + 1:
            self.missed += sample.seq - previous_seq - 1
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
