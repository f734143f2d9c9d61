"""The navigation service's settings: its prefix, where its odometry frame sits on the map, a geofence, and the
defaults of its live parameters (``nav/params``), under the same precedence rules as every service.

``map_pose`` is ``X,Y,YAW`` (m, m, rad) on the command line and in ``BLACKMETAL_MAP_POSE``, ``[x, y, yaw]`` in a
settings file or a fleet file's ``[robot.nav]``; ``geofence`` is ``XMIN,YMIN,XMAX,YMAX`` in the map frame (none: no
fence).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

from blackmetal.runtime.settings import setting
from blackmetal.runtime.zenoh_setup import ZenohSettings
from blackmetal.schemas import DEFAULT_PREFIX, ConfigError, MapPose, validate_prefix

from .params import NavParams

_DEFAULTS = NavParams()


def _param(name: str, help: str, metavar: str) -> float:
    """A setting that is the start value of the live parameter ``name``: its default is NavParams'."""
    return setting(getattr(_DEFAULTS, name), help + " (a live parameter: nav/params/set changes it)", metavar=metavar)


@dataclass(slots=True)
class NavSettings:
    prefix: str = setting(DEFAULT_PREFIX, "key-expression prefix, e.g. fleet/a")
    map_pose: list[float] = setting(
        help="where the odometry frame sits on the map (map -> odom): X,Y,YAW in m, m, rad; write --map-pose=-1,2,0 for a negative X",
        factory=lambda: [0.0, 0.0, 0.0],
        metavar="X,Y,YAW",
        comma=True,
    )
    map: str = setting("map", "the name of the site map that goals in the frame `map` refer to")
    geofence: list[float] = setting(
        help="refuse goals outside this rectangle of the map: XMIN,YMIN,XMAX,YMAX in m (default: no fence)",
        factory=list,
        metavar="XMIN,YMIN,XMAX,YMAX",
        comma=True,
    )
    max_speed: float = _param("max_speed", "fastest forward speed a goal is driven at, m/s", "M/S")
    max_turn: float = _param("max_turn", "fastest turn rate, rad/s", "RAD/S")
    linear_accel: float = _param("linear_accel", "forward acceleration and braking, m/s²", "M/S2")
    angular_accel: float = _param("angular_accel", "turn acceleration, rad/s²", "RAD/S2")
    xy_tolerance: float = _param("xy_tolerance", "a goal is reached within this distance, m", "M")
    yaw_tolerance: float = _param("yaw_tolerance", "and within this heading, rad", "RAD")
    max_goal_distance: float = _param("max_goal_distance", "refuse goals further than this from the robot, m", "M")
    reverse_distance: float = _param("reverse_distance", "drive backwards to a goal behind the robot at most this far, m (0: never)", "M")
    override_timeout: float = _param("override_timeout", "abort a goal a higher-priority source has overridden this long, s", "S")
    pose_timeout: float = _param("pose_timeout", "stop and abort when no pose came for this long, s", "S")
    no_progress_timeout: float = _param("no_progress_timeout", "abort a goal that came no closer for this long, s", "S")
    feedback_hz: float = _param("feedback_hz", "nav/feedback publications a second while a goal runs", "HZ")
    command_hz: float = setting(
        0.0,
        "velocity commands a second at most, the newest sent at its turn, a stop at once (0: one per pose, as the core "
        "makes them); fewer spare a fleet gateway (docs/performance.md)",
        metavar="HZ",
    )
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)

    def check(self) -> None:
        validate_prefix(self.prefix)
        if len(self.map_pose) != 3 or not all(math.isfinite(v) for v in self.map_pose):
            raise ConfigError(f"map_pose must be three finite numbers X,Y,YAW (m, m, rad), got {self.map_pose}")
        if not self.map.strip():
            raise ConfigError("map must name the site map, e.g. map or floor2")
        if self.geofence:
            if len(self.geofence) != 4 or not all(math.isfinite(v) for v in self.geofence):
                raise ConfigError(f"geofence must be four finite numbers XMIN,YMIN,XMAX,YMAX (m), got {self.geofence}")
            x_min, y_min, x_max, y_max = self.geofence
            if not (x_min < x_max and y_min < y_max):
                raise ConfigError(f"geofence {self.geofence}: XMIN must be below XMAX and YMIN below YMAX (XMIN,YMIN,XMAX,YMAX)")
        self.params().check()  # each live parameter within its range, as nav/params/set would have it
        if not (math.isfinite(self.command_hz) and 0.0 <= self.command_hz <= 1000.0):
            raise ConfigError(f"command_hz must be from 0 (one command per pose) to 1000, got {self.command_hz:g}")

    def params(self) -> NavParams:
        """The live parameters' start values (a parameter with no setting of its name keeps NavParams' default)."""
        names = {f.name for f in dataclasses.fields(self)}
        return NavParams(**{f.name: float(getattr(self, f.name)) for f in dataclasses.fields(NavParams) if f.name in names})

    def start_map_pose(self, wallclock: float | None = None) -> MapPose:
        """``map -> odom`` as the settings place it, by ``settings``."""
        x, y, yaw = self.map_pose
        return MapPose(stamp=time.time() if wallclock is None else wallclock, x=x, y=y, yaw=yaw, map=self.map, by="settings")

    def fence(self) -> tuple[float, float, float, float] | None:
        """The geofence, map frame x_min, y_min, x_max, y_max; None: none."""
        if not self.geofence:
            return None
        x_min, y_min, x_max, y_max = self.geofence
        return (x_min, y_min, x_max, y_max)
