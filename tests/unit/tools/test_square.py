"""square: the UMBmark figure from closures, the approach that a command timeout allows, the closure and its report."""

from __future__ import annotations

import math

import pytest

from blackmetal.schemas import make_pose
from blackmetal.tools.square import MAX_APPROACH_GAIN, Closure, Run, approach_gain, closure, report, umbmark_figure


def test_square_prints_the_true_ends_and_umbmarks_return_error() -> None:
    """`square --both`: E_max,syst from the true ends less the odometry's, and a calibrate command with the true ends."""

    runs = [
        Run("counter-clockwise", odometry=Closure(0.002, 0.001, 0.0), truth=Closure(-0.022, 0.029, 0.0)),
        Run("clockwise", odometry=Closure(0.001, 0.002, 0.0), truth=Closure(-0.014, -0.014, 0.0)),
    ]
    figure = umbmark_figure(runs)
    assert figure is not None
    assert "UMBmark E_max,syst 36.9 mm" in figure  # hypot(-0.024, 0.028), not the true end's 36.4 mm
    assert figure.endswith("blackmetal calibrate RECORDING --cw-end=-0.0140,-0.0140 --ccw-end=-0.0220,0.0290")
    assert umbmark_figure(runs[:1]) is None  # one direction only
    assert umbmark_figure([Run("clockwise", odometry=Closure(0, 0, 0), truth=None), runs[0]]) is None  # no truth


def test_square_approaches_a_corner_no_faster_than_the_command_timeout_allows() -> None:
    """A stalled square's last command runs for the gateway's command timeout: at gain 1/timeout it ends at the corner."""

    assert approach_gain(0.5) == 2.0
    assert approach_gain(0.15) == pytest.approx(1 / 0.15)
    assert approach_gain(0.0) == 2.0  # no timeout: the default's gain, not an unbounded one
    assert approach_gain(0.01) == MAX_APPROACH_GAIN


def test_a_closure_is_in_the_start_frame_and_reported_against_the_truth() -> None:
    start, end = make_pose(0.0, 1.0, 1.0, math.pi / 2), make_pose(1.0, 1.0, 1.1, math.pi / 2 + 0.01)
    c = closure(start, end)
    assert (c.dx, c.dy, c.dyaw) == pytest.approx((0.1, 0.0, 0.01))
    assert c.as_dict()["distance_m"] == pytest.approx(0.1)
    text = report(Run("clockwise", odometry=c, truth=Closure(0.1, 0.003, 0.01)))
    assert text.splitlines()[0] == "clockwise: odometry closure 100.0 mm (dx +100.0, dy +0.0), yaw +10.0 mrad"
    assert text.splitlines()[2].strip() == "odometry error 3.0 mm, 0.0 mrad"
