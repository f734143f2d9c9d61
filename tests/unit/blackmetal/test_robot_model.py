"""The robot model: one wheel order, one sin(h)/h, the same arithmetic streaming and batch."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from blackmetal.robot_model import WheelGain, WheelSpeeds, arc_path, arc_step, sin_ratio, twist_to_wheels


def test_wheel_pairs_are_keyword_only_left_then_right() -> None:
    with pytest.raises(TypeError):
        WheelSpeeds(0.1, 0.2)  # type: ignore[misc]
    with pytest.raises(TypeError):
        WheelGain(1.0, 1.1)  # type: ignore[misc]
    wheels, _ = twist_to_wheels(0.1, 0.4, 0.5, 0.8)  # a left turn: the right wheel is faster
    assert wheels.right > wheels.left
    assert wheels.scaled(WheelGain(left=0.5, right=2.0)) == WheelSpeeds(left=wheels.left * 0.5, right=wheels.right * 2.0)


@given(st.floats(-1.0, 1.0, allow_nan=False))
def test_sin_ratio_is_one_function_for_scalars_and_arrays(half: float) -> None:
    from blackmetal.robot_model import _sin_ratio

    scalar = sin_ratio(half)
    assert scalar == _sin_ratio(np.array([half]))[0]  # bit for bit: streaming and batch odometry agree
    assert scalar == pytest.approx(1.0 if half == 0 else math.sin(half) / half, rel=1e-15, abs=1e-15)


def test_arc_step_and_arc_path_agree() -> None:
    rng = np.random.default_rng(5)
    d_left, d_right = rng.uniform(-0.02, 0.03, 500), rng.uniform(-0.02, 0.03, 500)
    x = y = yaw = 0.0
    for a, b in zip(d_left.tolist(), d_right.tolist(), strict=True):
        x, y, yaw = arc_step(x, y, yaw, a, b, 0.5)
    xs, ys, yaws = arc_path(d_left, d_right, 0.5)
    assert (xs[-1], ys[-1], yaws[-1]) == pytest.approx((x, y, yaw), abs=1e-12)
