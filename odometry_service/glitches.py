"""Spike, dropout and stop rules for both wheels, with the low-pass: steps 2 and 3 of the pipeline.

Apart from the integration so the rules can be tested on readings alone; :mod:`.batch` has them in numpy.
"""

from __future__ import annotations

from dataclasses import dataclass


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


#: What a sample of two standing wheels gives (nothing to integrate, nothing to revise).
_STANDING = Update(0.0, 0.0, 0.0, 0.0, None, None)


class Glitches:
    """The rules sample by sample (docs/commands/odometry.md, "Glitches"): a dropout is estimated, and the next
    sample revises the previous step when it was a real stop or a joint start's dropped first reading."""

    def __init__(self, alpha: float, spike_limit: float) -> None:
        self.alpha = alpha
        self.limit = spike_limit
        self.spikes = 0
        self.dropouts = 0
        self.reset()

    def reset(self) -> None:
        self.left, self.right = WheelState(), WheelState()
        self.started = False  # a previous sample exists in this epoch
        self.started2 = False  # two previous samples exist in this epoch

    def _clip(self, value: float) -> float:
        return max(-self.limit, min(self.limit, value))

    def update(self, raw_left: float, raw_right: float) -> Update:
        """:meth:`_update` with its two common cases written out (docs/performance.md); a property test holds them equal."""
        left, right, limit = self.left, self.right, self.limit
        if raw_left == 0.0 and raw_right == 0.0 and left.zero_run == 2 and right.zero_run == 2:
            for state, raw, raw_other in ((left, raw_left, raw_right), (right, raw_right, raw_left)):
                if state.raw_prev == 0.0:
                    state.anchor, state.anchor_other, state.anchor_other_ok = raw, raw_other, True
                state.raw_prev = raw
                state.prev2, state.prev = state.prev, raw
                state.y = 0.0
            self.started2, self.started = self.started, True
            return _STANDING
        if (
            left.zero_run == 0
            and right.zero_run == 0
            and raw_left != 0.0
            and raw_right != 0.0
            and -limit <= raw_left <= limit
            and -limit <= raw_right <= limit
        ):
            alpha = self.alpha
            left.y = alpha * left.y + (1.0 - alpha) * raw_left
            right.y = alpha * right.y + (1.0 - alpha) * raw_right
            left.anchor, left.anchor_other, left.anchor_other_ok = raw_left, raw_right, True
            right.anchor, right.anchor_other, right.anchor_other_ok = raw_right, raw_left, True
            left.raw_prev, right.raw_prev = raw_left, raw_right
            left.prev2, left.prev = left.prev, raw_left
            right.prev2, right.prev = right.prev, raw_right
            self.started2, self.started = self.started, True
            return Update(raw_left, raw_right, left.y, right.y, None, None)
        return self._update(raw_left, raw_right)

    def _update(self, raw_left: float, raw_right: float) -> Update:
        """:meth:`update`, every rule applied in turn (the reference its written-out cases are tested against)."""
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
