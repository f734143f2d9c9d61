"""The streaming pipeline (:mod:`.integrator`) vectorised with numpy for replays; the poses agree to 1e-9.

Same rules and the same sums in the same order; the filter recursion is a parallel prefix scan. An
irregular log (sequence or stamps going back) is first cleaned by the live acceptance rules in a loop.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from blackmetal.robot_model import arc_deltas, arc_path, both, wheels_to_twist

from .errors import SampleRejected
from .params import OdometryParams
from .sample_order import EpochTally, SampleOrder, gap_event

F = NDArray[np.float64]
B = NDArray[np.bool_]


@dataclass
class BatchResult:
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
) -> tuple[B, B, list[str], list[str], EpochTally]:
    """Which samples are accepted and which start a new epoch, by :class:`SampleOrder`; ``time``: mono or stamps."""
    n = len(seq)
    dseq = np.diff(seq)
    dtime = np.diff(time)
    one_source = sources is None or len(set(sources)) == 1
    if one_source and bool(np.all(dseq > 0)) and bool(np.all(dtime >= 0)):  # a well-formed log: one vectorised pass
        accepted = np.ones(n, bool)
        new_epoch = np.empty(n, bool)
        new_epoch[:1] = True
        new_epoch[1:] = dtime > max_gap
        gap_idx = np.flatnonzero(new_epoch[1:]) + 1
        events = [gap_event(float(time[k] - time[k - 1]), int(seq[k]), max_gap) for k in gap_idx]
        return accepted, new_epoch, [], events, EpochTally(gaps=len(gap_idx), missed=int(np.sum(dseq - 1)))
    order = SampleOrder(max_gap, live=False)  # a log: older ones lack mono and source
    accepted = np.zeros(n, bool)
    new_epoch = np.zeros(n, bool)
    rejected: list[str] = []
    events = []
    tally = EpochTally()
    uses_mono = time is not stamp
    for k in range(n):
        source = None if sources is None else sources[k]
        try:
            verdict = order.check(int(seq[k]), float(stamp[k]), float(time[k]) if uses_mono else None, source, None)
        except SampleRejected as exc:
            rejected.append(str(exc))
            continue
        tally.count(verdict)
        if verdict.event is not None:
            events.append(verdict.event)
        accepted[k] = True
        new_epoch[k] = verdict.new_epoch
    return accepted, new_epoch[accepted], rejected, events, tally


#: The unit roundoff of float64: a carried factor below it changes no result by as much as its last bit.
UNIT_ROUNDOFF = 2.0**-53


def linear_scan(a: F, b: F, tol: float = UNIT_ROUNDOFF) -> F:
    """``y[k] = a[k] * y[k-1] + b[k]`` with ``y[-1] = 0``, as a parallel prefix scan.

    Stops once every carried factor is below ``tol``: after a round they are products of ``2 * shift``
    of the ``a``, so ``max|a| ** (2 * shift)`` bounds them without looking.
    """
    a = a.copy()
    y = b.copy()
    n = len(y)
    scratch = np.empty(n)
    bound = float(np.max(np.abs(a))) if n else 0.0
    shift = 1
    while shift < n and bound >= tol:
        carried = a[shift:]
        term = np.multiply(carried, y[:-shift], out=scratch[: n - shift])
        y[shift:] += term
        bound *= bound
        if 2 * shift < n and bound >= tol:  # another round follows
            carried *= a[:-shift]  # numpy reads the overlapping operand as it was
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
    epoch start), scaled by how the other wheel changed since when it can tell; the repair touches only the spikes."""
    valid = np.abs(x) <= limit
    if valid.all():
        return x, 0
    raw_prev = _prev(x, 0.0)
    raw_prev[new_epoch] = 0.0
    first_zero = (x == 0.0) & (raw_prev != 0.0)
    anchors = np.flatnonzero((valid & ~first_zero) | new_epoch)
    spikes = np.flatnonzero(~valid)
    # the last anchor at or before each spike (0 when there is none, the streaming reset state)
    before = np.searchsorted(anchors, spikes, side="right") - 1
    last = np.where(before >= 0, anchors[before] if anchors.size else 0, 0)
    # an epoch start that is itself not trustworthy anchors at 0
    trusted = valid[last] & ~first_zero[last]
    base = np.where(trusted, x[last], 0.0)
    other_base = np.where(trusted, x_other[last], 0.0)
    other_now = x_other[spikes]
    scale = (np.abs(other_now) <= limit) & trusted & (np.abs(x_other[last]) <= limit) & (other_now != 0.0) & (other_base != 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        scaled = np.clip(base * other_now / np.where(scale, other_base, 1.0), -limit, limit)
    clean = x.copy()
    clean[spikes] = np.where(scale, scaled, base)
    return clean, len(spikes)


def _zero_runs_before(zero: B, new_epoch: B) -> tuple[B, B, B]:
    """Where the samples just before are: a reading (run 0), one zero after a reading (run 1),
    or more zeros, or nothing in the epoch (run 2: "from rest"). Boolean masks, no int arrays."""
    zero_before = _prev(zero, True)  # the previous sample read zero (or there is none)
    reading_before = ~zero_before & ~new_epoch
    # the previous sample was a first zero: it read zero after a reading within its epoch
    first_zero_before = _prev(zero & ~_prev(zero, True) & ~new_epoch, False) & ~new_epoch
    return reading_before, first_zero_before, ~(reading_before | first_zero_before)


def _glitches(c: F, c_other: F, new_epoch: B, alpha: float, limit: float) -> tuple[F, F, NDArray[np.intp], F, int]:
    """One wheel's speeds to integrate, filtered speeds, revisions (sample ``k`` revises step ``k - 1``:
    indices ``k`` and values) and dropout count, by :class:`.glitches.Glitches`' rules, worked out only where they act."""
    zero = c == 0.0
    zero_o = c_other == 0.0
    run0, run1, reset = _zero_runs_before(zero, new_epoch)
    # a first zero in motion: a dropout until the next sample says otherwise; held, or scaled by
    # how the other wheel changed when it can tell (k >= 1: an epoch start is from rest)
    first = np.flatnonzero(zero & run0)
    u = c.copy()
    if first.size:
        held = c[first - 1]
        estimate = ~zero_o[first - 1] & ~zero_o[first]
        k = first[estimate]
        held[estimate] = np.clip(c[k - 1] * c_other[k] / c_other[k - 1], -limit, limit)
        u[first] = held
    moving = u != 0.0
    a = (moving & ~reset) * alpha
    b = u * (1.0 - alpha)  # 0 where not moving: u is 0 there
    from_rest = np.flatnonzero(moving & reset)
    b[from_rest] = u[from_rest]  # from rest: no slow ramp
    y = linear_scan(a, b)
    # revisions, where two previous samples exist in the epoch: a second zero was a real stop
    # (unless the other wheel stops only now), or a start's first reading was dropped
    second = np.flatnonzero(zero & run1)
    second = second[second >= 1]
    second = second[~new_epoch[second] & ~new_epoch[second - 1] & ~(~zero_o[second - 1] & zero_o[second])]
    start = np.flatnonzero(~zero & reset)
    start = start[start >= 1]
    other_still_before = np.where(start >= 2, zero_o[start - 2], True)
    start = start[~new_epoch[start] & ~new_epoch[start - 1] & other_still_before & ~zero_o[start - 1] & ~zero_o[start]]
    late = np.clip(c[start] * c_other[start - 1] / c_other[start], -limit, limit)
    revised = np.concatenate([second, start])  # disjoint: a second zero reads 0, a start does not
    values = np.concatenate([np.zeros(len(second)), late])
    dropouts = len(first) - len(second)
    return u, y, revised, values, dropouts


def run_batch(
    seq: NDArray[np.int64],
    stamp: F,
    left: NDArray[np.int64] | F,
    right: NDArray[np.int64] | F,
    params: OdometryParams | None = None,
    mono: F | None = None,
    sources: list[str | None] | None = None,
) -> BatchResult:
    """The pose after every accepted sample of a log, as the live service publishes it; ``mono``/``sources`` if logged."""
    p = params or OdometryParams()
    seq = np.asarray(seq, np.int64)
    stamp = np.asarray(stamp, np.float64)
    time = stamp if mono is None else np.asarray(mono, np.float64)
    accepted, new_epoch, rejected, events, tally = _acceptance(seq, stamp, time, sources, p.max_gap)
    left_imp = np.asarray(left, np.float64)
    right_imp = np.asarray(right, np.float64)
    if not accepted.all():
        stamp, time, left_imp, right_imp = stamp[accepted], time[accepted], left_imp[accepted], right_imp[accepted]
    n = len(stamp)
    x_left, x_right = p.encoders.to_speeds(left_imp, right_imp)
    (c_left, spikes_l), (c_right, spikes_r) = both(
        lambda: _clean(x_left, x_right, new_epoch, p.spike_limit), lambda: _clean(x_right, x_left, new_epoch, p.spike_limit), n
    )
    (u_left, y_left, fix_l, rev_left, drops_l), (u_right, y_right, fix_r, rev_right, drops_r) = both(
        lambda: _glitches(c_left, c_right, new_epoch, p.filter_alpha, p.spike_limit),
        lambda: _glitches(c_right, c_left, new_epoch, p.filter_alpha, p.spike_limit),
        n,
    )

    dt = np.zeros(n)
    dt[1:] = np.diff(time)
    dt[new_epoch] = 0.0  # no step into an epoch's first sample
    # sample k revises step k - 1; the live service first published the step as held
    provisional = np.union1d(fix_l, fix_r) - 1
    held_l, held_r = u_left[provisional] * dt[provisional], u_right[provisional] * dt[provisional]
    u_left[fix_l - 1] = rev_left
    u_right[fix_r - 1] = rev_right
    d_left = u_left * dt
    d_right = u_right * dt

    x, y, yaw = integrate(d_left, d_right, p.wheel_separation)

    # what the live service published at a first zero later shown to be a stop: the held step
    if provisional.size:
        k = provisional
        x_prev, y_prev, yaw_prev = (np.where(k > 0, path[k - 1], 0.0) for path in (x, y, yaw))
        pdx, pdy, pdth = arc_deltas(yaw_prev, held_l, held_r, p.wheel_separation)
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
        retractions=len(provisional),
        gaps=tally.gaps,
        restarts=tally.restarts,
        missed=tally.missed,
        d_left=d_left,
        d_right=d_right,
    )


def integrate(d_left: F, d_right: F, separation: float) -> tuple[F, F, F]:
    """Poses (x, y, unwrapped yaw) after each step from the wheels' travels: what a calibration re-runs."""
    return arc_path(d_left, d_right, separation)
