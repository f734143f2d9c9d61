"""The navigation bench's baseline: the time a trapezoidal profile needs, and the plan it is measured against."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time

import pytest

from blackmetal.bench.navigation import GOALS, _child_pids, reference_time, trapezoid_time

LIMITS = {"max_speed": 0.3, "max_turn": 1.2, "linear_accel": 0.5, "angular_accel": 2.0, "xy_tolerance": 0.01}


def test_a_long_move_cruises_and_pays_one_ramp() -> None:
    # 10 m at 0.3 m/s with 0.5 m/s^2: 10 / 0.3 + 0.3 / 0.5
    assert trapezoid_time(10.0, 0.3, 0.5) == pytest.approx(10.0 / 0.3 + 0.6)


def test_a_short_move_is_a_triangle_that_never_reaches_top_speed() -> None:
    # 1 cm: accelerate over half, brake over the other: 2 * sqrt(d / a)
    assert trapezoid_time(0.01, 0.3, 0.5) == pytest.approx(2 * math.sqrt(0.01 / 0.5))
    assert trapezoid_time(-0.01, 0.3, 0.5) == trapezoid_time(0.01, 0.3, 0.5)


def test_the_profile_is_continuous_where_the_triangle_becomes_a_trapezoid() -> None:
    edge = 0.3 * 0.3 / 0.5
    assert trapezoid_time(edge * (1 - 1e-9), 0.3, 0.5) == pytest.approx(trapezoid_time(edge * (1 + 1e-9), 0.3, 0.5), rel=1e-6)


def test_without_an_acceleration_limit_it_is_distance_over_speed() -> None:
    assert trapezoid_time(3.0, 0.3, 0.0) == pytest.approx(10.0)


def test_a_goal_behind_pays_a_half_turn_then_the_drive() -> None:
    took = reference_time((0.0, 0.0, 0.0), (-1.0, 0.0, None), LIMITS)
    assert took == pytest.approx(trapezoid_time(math.pi, 1.2, 2.0) + trapezoid_time(1.0, 0.3, 0.5))


def test_a_turn_on_the_spot_pays_only_the_turn_and_takes_the_short_way() -> None:
    assert reference_time((0.0, 0.0, 3.0), (0.0, 0.0, -3.0), LIMITS) == pytest.approx(trapezoid_time(math.tau - 6.0, 1.2, 2.0))


def test_a_goal_with_a_yaw_turns_to_it_from_the_bearing_it_drove() -> None:
    took = reference_time((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), LIMITS)
    assert took == pytest.approx(2 * trapezoid_time(math.pi / 2, 1.2, 2.0) + trapezoid_time(1.0, 0.3, 0.5))


def test_the_twenty_goals_hold_what_the_issue_names() -> None:
    assert len(GOALS) == 20
    distances = [math.hypot(f, left) for f, left, _ in GOALS]
    assert any(d == 0 for d in distances), "turns on the spot"
    assert any(f < 0 for f, _, _ in GOALS), "goals behind the robot"
    assert any(0 < d <= 0.011 for d in distances), "1 cm away"
    assert max(distances) >= 10.0, "10 m away"


def test_the_services_of_a_parent_are_found_by_their_subcommand() -> None:
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)", "blackmetal", "nav", "--fleet", "x"])
    try:
        deadline = time.monotonic() + 10
        while "nav" not in (found := _child_pids(os.getpid())) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert found.get("nav") == child.pid
    finally:
        child.kill()
        child.wait()
