"""``blackmetal replay --compare``: the replay set against live poses that did not start at zero."""

from __future__ import annotations

import math
import re

import numpy as np

from blackmetal.schemas import make_pose
from blackmetal.tools.replay import compare_poses


def test_a_recording_that_starts_mid_run_compares_the_motion_not_the_origin() -> None:
    # the replay: a quarter circle from (0, 0, 0); the live odometry drove the same arc from (2, -1, 1.2)
    t = np.linspace(0.0, 5.0, 501)
    yaw = 0.3 * t
    x, y = np.sin(yaw) / 0.3 * 0.5, (1 - np.cos(yaw)) / 0.3 * 0.5
    c, s = math.cos(1.2), math.sin(1.2)
    live = [make_pose(float(t[k]), 2.0 + c * x[k] - s * y[k], -1.0 + s * x[k] + c * y[k], 1.2 + yaw[k]) for k in range(0, 501, 10)]
    line = compare_poses(t, x, y, yaw, live)
    mm, mrad = (float(v) for v in re.search(r"largest difference ([\d.]+) mm .*, ([\d.]+) mrad", line).groups())  # type: ignore[union-attr]
    assert mm < 1e-6 and mrad < 1e-6, line
    assert "51 of 51" in line and "x 2.000 m, y -1.000 m, yaw 1.200 rad" in line
    # a real difference still shows: the live pose drifts 5 cm sideways by the end
    live[-1] = make_pose(live[-1].stamp, live[-1].x + 0.05, live[-1].y, live[-1].yaw)
    assert "largest difference 50.000 mm" in compare_poses(t, x, y, yaw, live)
