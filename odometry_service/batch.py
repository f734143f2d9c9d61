"""The odometry pipeline of :mod:`odometry_service.core`, vectorised with numpy for replays.

Same rules, same arithmetic order where it matters, so the poses agree with
the streaming path to 1e-9 (the filter recursion runs as a parallel prefix
scan; everything else is the same sums in the same order). For a well-formed
log (sequence increasing, stamps not going back) everything is one pass of
array operations; an irregular log is first cleaned by a short Python loop
that applies the streaming path's acceptance rules.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from blackmetal.robot_model import arc_deltas, wheels_to_twist

from .core import OdometryParams, SampleOrder
from .errors import SampleRejected

F = NDArray[np.float64]
B = NDArray[np.bool_]


@dataclass
class BatchResult:
    """Every published pose of the replay, as arrays, plus what was rejected or noticed."""

    stamp: F
    x: F
    y: F
    yaw: F  # unwrapped
    v: F
    w: F
    rejected: list[str] = field(default_factory=list)
    events: list[str] = field(default_factory=list)
    spikes: int = 0
    dropouts: int = 0
    retractions: int = 0
    gaps: int = 0
    restarts: int = 0
    missed: int = 0
    #: Rim travel of each wheel over each step (m), as integrated: what a calibration rescales.
    d_left: F | None = None
    d_right: F | None = None

    def __len__(self) -> int:
        return len(self.stamp)


def _acceptance(
    seq: NDArray[np.int64], stamp: F, time: F, sources: list[str | None] | None, max_gap: float
) -> tuple[B, B, list[str], list[str], int, int, int]:
    """Which samples are accepted and which start a new epoch, by the live rules (:class:`SampleOrder`).

    ``time`` is what intervals are measured on (``mono`` when the log has it, else the stamps).
    """
    n = len(seq)
    if n == 0:
        return np.zeros(0, bool), np.zeros(0, bool), [], [], 0, 0, 0
    dseq = np.diff(seq)
    dtime = np.diff(time)
    one_source = sources is None or len(set(sources)) == 1
    if one_source and bool(np.all(dseq > 0)) and bool(np.all(dtime >= 0)):  # a well-formed log: one vectorised pass
        accepted = np.ones(n, bool)
        new_epoch = np.empty(n, bool)
        new_epoch[0] = True
        new_epoch[1:] = dtime > max_gap
        gap_idx = np.flatnonzero(new_epoch[1:]) + 1
        events = [f"gap of {time[k] - time[k - 1]:.3f} s before seq {seq[k]} exceeds {max_gap} s: not integrated" for k in gap_idx]
        return accepted, new_epoch, [], events, len(gap_idx), 0, int(np.sum(dseq - 1))
    # an irregular log: the live rules, sample by sample
    order = SampleOrder(max_gap)
    accepted = np.zeros(n, bool)
    new_epoch = np.zeros(n, bool)
    rejected: list[str] = []
    events = []
    gaps = restarts = missed = 0
    uses_mono = time is not stamp
    for k in range(n):
        previous = order.seq
        source = None if sources is None else sources[k]
        try:
            verdict = order.check(int(seq[k]), float(stamp[k]), float(time[k]) if uses_mono else None, source, None)
        except SampleRejected as exc:
            rejected.append(str(exc))
            continue
        restart = verdict.event is not None and "gap" not in verdict.event
        if verdict.event is not None:
            events.append(verdict.event)
            restarts += restart
            gaps += not restart
        if previous is not None and not restart and seq[k] > previous + 1:
            missed += int(seq[k]) - previous - 1
        accepted[k] = True
        new_epoch[k] = verdict.new_epoch
    return accepted, new_epoch[accepted], rejected, events, gaps, restarts, missed


def linear_scan(a: F, b: F, tol: float = 1e-18) -> F:
    """``y[k] = a[k] * y[k-1] + b[k]`` with ``y[-1] = 0``, as a parallel prefix scan.

    Stops once every remaining carried factor is below ``tol`` (its effect on
    ``y`` is then far below floating-point resolution of the result).
    """
    a = a.copy()
    y = b.copy()
    n = len(y)
    shift = 1
    while shift < n:
        carried = a[shift:]
        if not carried.size or float(np.max(np.abs(carried))) < tol:
            break
        y[shift:] = y[shift:] + carried * y[:-shift]
        a[shift:] = carried * a[:-shift]
        shift *= 2
    return y


def _prev(values: np.ndarray, fill: object) -> np.ndarray:
    out = np.empty_like(values)
    if len(values):
        out[0] = fill
        out[1:] = values[:-1]
    return out


def _clean(x: F, x_other: F, new_epoch: B, limit: float) -> tuple[F, int]:
    """Spikes replaced by the last trustworthy reading (not a spike, not a first zero; 0 at an
    epoch start), scaled by how the other wheel changed since when it can tell."""
    index = np.arange(len(x))
    valid = np.abs(x) <= limit
    valid_o = np.abs(x_other) <= limit
    raw_prev = _prev(x, 0.0)
    raw_prev[new_epoch] = 0.0
    anchor = (valid & ~((x == 0.0) & (raw_prev != 0.0))) | new_epoch
    last = np.maximum.accumulate(np.where(anchor, index, 0))
    # an epoch start that is itself not trustworthy anchors at 0 (the streaming reset state)
    trusted = valid[last] & ~((x[last] == 0.0) & (raw_prev[last] != 0.0))
    base = np.where(trusted, x[last], 0.0)
    other_base = np.where(trusted, x_other[last], 0.0)
    other_ok = trusted & valid_o[last]
    scale = ~valid & valid_o & other_ok & (x_other != 0.0) & (other_base != 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        scaled = np.clip(base * x_other / np.where(scale, other_base, 1.0), -limit, limit)
    clean = np.where(valid, x, np.where(scale, scaled, base))
    return clean, int(np.count_nonzero(~valid))


def _zero_run_before(zero: B, new_epoch: B) -> NDArray[np.int8]:
    """Consecutive zeros (capped at 2) after the previous sample; 2 at an epoch start."""
    prev_nonzero = ~_prev(zero, True) & ~new_epoch
    zr_after = np.where(zero, np.where(prev_nonzero, 1, 2), 0).astype(np.int8)
    zr_before = _prev(zr_after, 2)
    zr_before[new_epoch] = 2
    return zr_before


def _glitches(c: F, c_other: F, new_epoch: B, alpha: float, limit: float) -> tuple[F, F, NDArray[np.float64], B, int]:
    """One wheel's speeds to integrate, filtered speeds, the revision of the previous step decided
    at each sample (NaN = none), and its dropout count; the rules of
    :class:`~odometry_service.core.Glitches`."""
    zero = c == 0.0
    zero_o = c_other == 0.0
    zr_before = _zero_run_before(zero, new_epoch)
    prev_c, prev_co = _prev(c, 0.0), _prev(c_other, 0.0)
    prev_zero_o = _prev(zero_o, True)
    first_zero = zero & (zr_before == 0)
    estimate = first_zero & ~prev_zero_o & ~zero_o
    with np.errstate(divide="ignore", invalid="ignore"):
        est_value = np.clip(np.where(estimate, prev_c * c_other / np.where(estimate, prev_co, 1.0), 0.0), -limit, limit)
    u = np.where(zero, np.where(first_zero, np.where(estimate, est_value, prev_c), 0.0), c)
    moving = u != 0.0
    reset = zr_before >= 2
    a = np.where(moving & ~reset, alpha, 0.0)
    b = np.where(moving, np.where(reset, u, (1.0 - alpha) * u), 0.0)
    y = linear_scan(a, b)
    # revisions of step k-1, decided at k (only where steps k-1 and k exist: two previous samples in the epoch)
    started = ~new_epoch
    started2 = started & _prev(started, False)
    retract = started2 & zero & (zr_before == 1) & ~(~prev_zero_o & zero_o)
    late = started2 & ~retract & ~zero & (zr_before >= 2) & _prev(prev_zero_o, True) & ~prev_zero_o & ~zero_o
    with np.errstate(divide="ignore", invalid="ignore"):
        late_value = np.clip(np.where(late, c * prev_co / np.where(late, c_other, 1.0), 0.0), -limit, limit)
    revision = np.where(retract, 0.0, np.where(late, late_value, np.nan))
    dropouts = int(np.count_nonzero(first_zero)) - int(np.count_nonzero(retract))
    return u, y, revision, retract | late, dropouts


def run_batch(
    seq: NDArray[np.int64],
    stamp: F,
    left: NDArray[np.int64] | F,
    right: NDArray[np.int64] | F,
    params: OdometryParams | None = None,
    mono: F | None = None,
    sources: list[str | None] | None = None,
) -> BatchResult:
    """Replay a whole impulse log; the pose after every accepted sample, as the live service publishes it.

    ``mono``/``sources``: the samples' monotonic times and gateway ids, when the log has them.
    """
    p = params or OdometryParams()
    seq = np.asarray(seq, np.int64)
    stamp = np.asarray(stamp, np.float64)
    time = stamp if mono is None else np.asarray(mono, np.float64)
    accepted, new_epoch, rejected, events, gaps, restarts, missed = _acceptance(seq, stamp, time, sources, p.max_gap)
    left_imp = np.asarray(left, np.float64)
    right_imp = np.asarray(right, np.float64)
    if not accepted.all():
        stamp, time, left_imp, right_imp = stamp[accepted], time[accepted], left_imp[accepted], right_imp[accepted]
    n = len(stamp)
    x_left, x_right = p.encoders.to_speeds(left_imp, right_imp)
    c_left, spikes_l = _clean(x_left, x_right, new_epoch, p.spike_limit)
    c_right, spikes_r = _clean(x_right, x_left, new_epoch, p.spike_limit)
    u_left, y_left, rev_left, fix_l, drops_l = _glitches(c_left, c_right, new_epoch, p.filter_alpha, p.spike_limit)
    u_right, y_right, rev_right, fix_r, drops_r = _glitches(c_right, c_left, new_epoch, p.filter_alpha, p.spike_limit)

    dt = np.zeros(n)
    if n > 1:
        dt[1:] = np.diff(time)
    dt[new_epoch] = 0.0
    has_step = ~new_epoch
    revised_at = fix_l | fix_r  # sample k revises step k-1
    s_left = u_left.copy()
    s_right = u_right.copy()
    fix_left = np.zeros(n, bool)
    fix_right = np.zeros(n, bool)
    fix_left[:-1] = fix_l[1:]
    fix_right[:-1] = fix_r[1:]
    s_left[fix_left] = rev_left[1:][fix_l[1:]]
    s_right[fix_right] = rev_right[1:][fix_r[1:]]
    d_left = np.where(has_step, s_left * dt, 0.0)
    d_right = np.where(has_step, s_right * dt, 0.0)

    x, y, yaw = integrate(d_left, d_right, p.wheel_separation)

    # what the live service published at a first zero later shown to be a stop: the held step
    provisional = np.flatnonzero(fix_left | fix_right)
    if provisional.size:
        k = provisional
        x_prev = np.where(k > 0, x[k - 1], 0.0)
        y_prev = np.where(k > 0, y[k - 1], 0.0)
        yaw_prev = np.where(k > 0, yaw[k - 1], 0.0)
        held_l, held_r = u_left[k] * dt[k], u_right[k] * dt[k]
        pdx, pdy, pdth = arc_deltas(yaw_prev, held_l, held_r, p.wheel_separation)
        x = x.copy()
        y = y.copy()
        yaw = yaw.copy()
        x[k], y[k], yaw[k] = x_prev + pdx, y_prev + pdy, yaw_prev + pdth

    v, w = wheels_to_twist(y_left, y_right, p.wheel_separation)
    return BatchResult(
        stamp=stamp,
        x=x,
        y=y,
        yaw=yaw,
        v=v,
        w=w,
        rejected=rejected,
        events=events,
        spikes=spikes_l + spikes_r,
        dropouts=drops_l + drops_r,
        retractions=int(np.count_nonzero(revised_at)),
        gaps=gaps,
        restarts=restarts,
        missed=missed,
        d_left=d_left,
        d_right=d_right,
    )


def integrate(d_left: F, d_right: F, separation: float) -> tuple[F, F, F]:
    """Poses (x, y, unwrapped yaw) after each step from the wheels' travels: exact arcs, one numpy pass.

    The whole of the odometry's geometry; a calibration calls it many times
    with rescaled travels and another separation.
    """
    yaw = np.cumsum(wheels_to_twist(d_left, d_right, separation)[1])  # turn of each step
    yaw_before = np.empty(len(yaw))
    if len(yaw):
        yaw_before[0] = 0.0
        yaw_before[1:] = yaw[:-1]
    dx, dy, _ = arc_deltas(yaw_before, d_left, d_right, separation)
    return np.cumsum(dx), np.cumsum(dy), yaw
