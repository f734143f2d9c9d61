"""The glitch rules and the low-pass (:mod:`blackmetal.odometry_service.glitches`), on readings alone.

Rim speeds in m/s, a spike limit of 0.84 (the robot's 0.8 m/s and 5 %):
a spike is replaced, a single zero in motion is a dropout until the next
reading settles it, and a step proved wrong is revised.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from blackmetal.odometry_service.glitches import Glitches


def test_filter_rules_on_one_wheel() -> None:
    g = Glitches(alpha=0.5, spike_limit=0.84)

    def left(x: float) -> tuple[float, float, float | None]:
        update = g.update(x, 0.0)  # the right wheel stands still: no cross-wheel estimate
        return update.left, update.filtered_left, update.revise_left

    assert left(0.4) == (0.4, 0.4, None)  # from rest: no ramp
    assert left(0.2) == (0.2, pytest.approx(0.3), None)  # low-pass on the published speed
    assert left(0.0) == (0.2, pytest.approx(0.25), None)  # a single zero is held
    assert left(0.3) == (0.3, pytest.approx(0.275), None)  # ... and it was a dropout
    assert left(0.0)[0] == 0.3
    assert left(0.0) == (0.0, 0.0, 0.0)  # second zero: a real stop; the held step is revised to 0
    assert left(0.0) == (0.0, 0.0, None)
    assert left(0.5) == (0.5, 0.5, None)  # first non-zero after a stop resets
    assert left(5.0) == (0.5, 0.5, None)  # a spike is replaced by the last trustworthy reading
    assert g.spikes == 1 and g.dropouts == 1


def test_a_dropout_while_both_wheels_change_keeps_the_curvature() -> None:
    g = Glitches(alpha=0.0, spike_limit=0.84)
    g.update(0.2, 0.1)
    update = g.update(0.0, 0.3)  # left dropped while the right went 0.1 -> 0.3
    assert (update.left, update.right) == (pytest.approx(0.6), 0.3)


def test_a_dropout_at_a_joint_stop_is_kept_and_a_dropped_start_is_restored() -> None:
    g = Glitches(alpha=0.0, spike_limit=0.84)
    g.update(0.3, 0.3)
    g.update(0.0, 0.15)  # left dropped on the last, partial interval before the stop
    update = g.update(0.0, 0.0)
    assert update.revise_left is None and update.revise_right is None  # the estimate (0.15) stands
    g.update(0.0, 0.0)
    g.update(0.0, 0.1)  # joint start, left's first reading dropped
    assert g.update(0.3, 0.3).revise_left == pytest.approx(0.1)


_reading = st.sampled_from([0.0, -0.0, 0.3, -0.3, 0.31, 1.2, -1.2, 9.0, -9.0, math.inf, math.nan]) | st.floats(-3.0, 3.0)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(_reading, _reading), max_size=40), st.floats(0.0, 0.95))
def test_the_written_out_glitch_cases_do_what_every_rule_does(readings: list[tuple[float, float]], alpha: float) -> None:
    fast, reference = Glitches(alpha, 2.0), Glitches(alpha, 2.0)

    def state(g: Glitches) -> str:
        return repr((g.left, g.right, g.spikes, g.dropouts, g.started, g.started2))

    for left, right in readings:
        assert repr(fast.update(left, right)) == repr(reference._update(left, right))
        assert state(fast) == state(reference)


def test_a_spike_is_the_last_good_reading_scaled_as_the_other_wheel_changed() -> None:
    g = Glitches(alpha=0.0, spike_limit=0.84)
    g.update(0.4, 0.2)
    update = g.update(5.0, 0.4)  # the right wheel doubled: the left is estimated to have too (the curvature kept)
    assert (update.left, update.right) == (pytest.approx(0.8), 0.4)
    update = g.update(-7.0, 0.8)  # scaled from the last trustworthy reading (0.4 at 0.2), never past the limit
    assert update.left == 0.84 and g.spikes == 2


def test_when_both_wheels_spike_each_holds_its_last_good_reading() -> None:
    g = Glitches(alpha=0.0, spike_limit=0.84)
    g.update(0.3, 0.5)
    update = g.update(math.inf, -9.0)
    assert (update.left, update.right) == (0.3, 0.5) and g.spikes == 2


def test_a_reset_forgets_the_wheels_but_keeps_the_counts() -> None:
    g = Glitches(alpha=0.5, spike_limit=0.84)
    g.update(0.4, 0.4)
    g.update(0.0, 0.4)  # a dropout
    g.reset()
    update = g.update(0.2, 0.2)  # from rest again: published as read, no ramp from the old filter state
    assert (update.filtered_left, update.filtered_right, update.revise_left) == (0.2, 0.2, None)
    assert g.dropouts == 1  # counted over the whole run, as the diagnostics show them
