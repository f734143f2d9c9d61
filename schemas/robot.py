"""Facts about the Black Metal robot that every part of the system agrees on.

The gateway, the odometry service and the simulator all take their defaults
from here, so a calibration change is made once.
"""

from __future__ import annotations

import math

#: Encoder impulses per metre of rim travel (= impulses/s per m/s), left wheel.
IMPULSES_PER_METER_LEFT = 1012.53636364
#: Same for the right wheel. Its encoder is mirrored: forward motion reads negative.
IMPULSES_PER_METER_RIGHT = 1053.67588345
#: The robot's own limit per wheel (m/s); a reading above it is a glitch.
MAX_WHEEL_SPEED = 0.8
#: Distance between the wheels (m), from the original driver's configuration.
WHEEL_SEPARATION = 0.5
#: Wheel radius (m).
WHEEL_RADIUS = 0.1
#: The robot stops its wheels by itself after this long without a motion command (s).
ROBOT_WATCHDOG_S = 10.0
#: Default TCP ports of the robot's control computer.
CONTROL_PORT = 665
LOG_PORT = 664
#: Default key-expression prefix.
DEFAULT_PREFIX = "robot"


def arc_step(x: float, y: float, yaw: float, d_left: float, d_right: float, separation: float) -> tuple[float, float, float]:
    """Move a differential-drive pose by wheel travels ``d_left``/``d_right`` along the exact arc.

    Chord form: length ``ds * sin(h)/h`` at heading ``yaw + h`` with ``h`` half
    the turn; exact for any turn and well conditioned as the turn goes to zero,
    where it becomes the straight line. The simulator's truth and the odometry
    both move this way.
    """
    ds = 0.5 * (d_left + d_right)
    dth = (d_right - d_left) / separation
    half = 0.5 * dth
    chord = ds * (math.sin(half) / half if abs(half) > 1e-6 else 1.0 - half * half / 6.0)
    heading = yaw + half
    return x + chord * math.cos(heading), y + chord * math.sin(heading), yaw + dth
