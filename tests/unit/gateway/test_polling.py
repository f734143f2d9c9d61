"""The poll grid: what a fleet's wake-ups and the health's poll rate rely on."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from blackmetal.gateway.polling import PollSchedule


def polls(schedule: PollSchedule, start: float, end: float, step: float = 0.0005) -> list[float]:
    """The times a host that looks every ``step`` s (and at every deadline) polls, from ``start`` to ``end``."""
    out, now = [], start
    while now < end:
        if schedule.due(now):
            out.append(now)
        now = min(now + step, schedule.next_deadline())
    return out


def test_the_first_poll_goes_out_at_once_and_the_rest_on_the_clock_grid() -> None:
    schedule = PollSchedule(50.0)
    schedule.start(1000.013)
    times = polls(schedule, 1000.013, 1000.1)
    assert times[0] == 1000.013
    assert times[1:] == pytest.approx([1000.04, 1000.06, 1000.08])  # 1000.02 is less than half a period on


def test_robots_whose_links_came_up_at_different_times_poll_at_the_same_instants() -> None:
    a, b = PollSchedule(50.0), PollSchedule(50.0)
    a.start(7.001)
    b.start(7.0137)
    assert a.due(7.001) and b.due(7.0137)
    # the link-up's poll, then the grid: its first instant at least half a period on (7.02 is 6.3 ms after b's)
    assert a.next_deadline() == pytest.approx(7.02) and b.next_deadline() == pytest.approx(7.04)
    first = a.next_deadline()
    assert a.due(first) and not b.due(first)
    second = max(a.next_deadline(), b.next_deadline())
    assert a.due(second) and b.due(second)
    assert a.next_deadline() == b.next_deadline() == pytest.approx(7.06)


def test_a_link_up_never_polls_twice_within_half_a_period() -> None:
    for start in (0.0, 0.0199, 0.0101, 0.0099, 123.45678):
        schedule = PollSchedule(50.0)
        schedule.start(start)
        assert schedule.due(start)
        assert 0.01 - 1e-9 <= schedule.next_deadline() - start <= 0.03 + 1e-9


def test_a_host_that_fell_behind_polls_once_and_takes_the_next_instant() -> None:
    schedule = PollSchedule(50.0)
    schedule.start(0.0)
    assert schedule.due(0.0)
    assert schedule.due(0.113)  # five periods late: one poll, not a burst of five
    assert not schedule.due(0.119)
    assert schedule.next_deadline() == pytest.approx(0.12)


@given(st.floats(0.0, 1e6), st.sampled_from([50.0, 100.0, 30.0, 7.0, 200.0]), st.floats(0.0, 0.2))
def test_a_poll_is_never_due_again_at_the_same_time(start: float, hz: float, late: float) -> None:
    schedule = PollSchedule(hz)
    schedule.start(start)
    assert schedule.due(start)
    now = schedule.next_deadline() + late
    assert now > start
    assert schedule.due(now)
    assert schedule.next_deadline() > now  # else the host's timer would fire again at once
    assert schedule.next_deadline() - now <= 1.0 / hz + 1e-6  # (the clock's seconds lose digits as they grow)


@pytest.mark.parametrize("start", [0.0, 4.0, 1000.013, 279621.125, 3.5e6])
@pytest.mark.parametrize("hz", [50.0, 30.0, 100.0, 7.0])
def test_a_host_that_wakes_at_each_deadline_polls_once_a_period(start: float, hz: float) -> None:
    """Grid instants computed as k x period divide back to a hair under k: each must still come due once."""
    schedule = PollSchedule(hz)
    schedule.start(start)
    now = start
    assert schedule.due(now)
    for _ in range(2000):
        now = schedule.next_deadline()
        assert schedule.due(now)
        assert schedule.next_deadline() - now == pytest.approx(1.0 / hz, abs=1e-6)
