"""A NavCore wired to a simulated robot and gateway, for the core's tests (test_core.py, test_core_endings.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import msgspec

from blackmetal.nav.core import NavCore
from blackmetal.nav.params import NavParams
from blackmetal.schemas import (
    DriverChange,
    ErrorReport,
    GatewayHealth,
    GatewayParams,
    Keys,
    LinkHealth,
    MapPose,
    NavFeedback,
    Twist,
    encode,
    make_pose,
)

from .kinematics import PERIOD, Robot

KEYS = Keys("robot")
GOAL_A, GOAL_B = "a" * 32, "b" * 32


@dataclass
class Out:
    """Everything the core published, by kind."""

    twists: list[Twist] = field(default_factory=list)
    feedback: list[NavFeedback] = field(default_factory=list)
    map_poses: list[MapPose] = field(default_factory=list)
    params: list[GatewayParams] = field(default_factory=list)
    errors: list[ErrorReport] = field(default_factory=list)
    #: Everything, in order (a test may add its own markers).
    log: list[object] = field(default_factory=list)

    def __call__(self, message: object) -> None:
        self.log.append(message)
        kinds = {
            Twist: self.twists,
            NavFeedback: self.feedback,
            MapPose: self.map_poses,
            GatewayParams: self.params,
            ErrorReport: self.errors,
        }
        kinds[type(message)].append(message)  # type: ignore[index]


def health(estop: bool = False, link: str = "connected", source: str | None = None, stamp: float = 0.0) -> bytes:
    reason = None if link == "connected" else "cannot connect to 192.0.2.1:665: Connection refused"
    return encode(
        GatewayHealth(
            stamp,
            LinkHealth(link, reason=reason),
            LinkHealth("connected"),
            estop=estop,
            active_source=source,
            estop_by="robot/estop" if estop else None,
            estop_since=1.8e9 if estop else None,
        )
    )


class Bench:
    """A NavCore wired to a simulated robot: the gateway runs the latest twist (its command timeout: 0.5 s), the
    odometry reports a pose every period, the core's deadlines are kept."""

    def __init__(self, map_pose: MapPose | None = None, geofence: tuple[float, float, float, float] | None = None, **params: float) -> None:
        self.out = Out()
        self.now = 0.0
        self.core = NavCore(
            NavParams(**params),
            KEYS,
            self.out,
            map_pose=map_pose or MapPose(0.0, 0.0, 0.0, 0.0),
            geofence=geofence,
            wallclock=lambda: 1.8e9 + self.now,
        )
        self.robot = Robot()
        self.moves = True  # the wheels follow the commands (False: blocked)
        self.arbiter = True  # the gateway says the nav drives once it commands (False: someone else keeps driving)
        self._driver: str | None = None
        self.poses = True  # the odometry publishes
        self._command = (0.0, 0.0)
        self._heard = -math.inf
        self._seen = 0  # twists the gateway has taken
        assert self.core.next_deadline() == -math.inf  # the first tick is due at once
        self.core.tick(self.now)
        self.core.on_alive("gateway", True, self.now)
        self.core.on_alive("odometry", True, self.now)
        self.core.on_health(health(), self.now)
        self.pose()

    def pose(self) -> None:
        x, y, yaw = self.robot.pose()
        self.core.on_pose(encode(make_pose(1.8e9 + self.now, x, y, yaw, self.robot.v, self.robot.w)), self.now)

    def run(self, seconds: float) -> None:
        """``seconds`` of robot time: a pose each period while ``poses``, the core ticked at its deadlines."""
        end = self.now + seconds - 1e-9
        while self.now < end:
            if self.poses:
                self.pose()
            if len(self.out.twists) > self._seen:  # the latest command, sent on this pose or on a query since the last
                self._seen = len(self.out.twists)
                t = self.out.twists[-1]
                self._command, self._heard = (t.linear.x, t.angular.z), self.now
                if self.arbiter and self._driver != "nav":
                    self._driver = "nav"
                    self.core.on_driver(encode(DriverChange(1.8e9 + self.now, "nav", None, "nav drives: nobody drove")), self.now)
            self._tick_until(self.now + PERIOD)
            if self.now - self._heard > 0.5:  # the gateway's command timeout
                self._command = (0.0, 0.0)
            self.robot.run(*(self._command if self.moves else (0.0, 0.0)))
            if not self.moves:
                self.robot.v = self.robot.w = 0.0
            self.now += PERIOD

    def _tick_until(self, until: float) -> None:
        for _ in range(100):
            due = self.core.next_deadline()
            if due >= until:
                return
            self.core.tick(max(due, self.now))
            if self.core.next_deadline() <= due:  # a deadline in the past not cleared: tick once more, not forever
                self.core.tick(max(due, self.now))
                return

    def goal(self, **fields: object) -> bytes:
        return msgspec.json.encode(fields)

    def until_done(self, timeout: float = 60.0) -> None:
        end = self.now + timeout
        while self.core.goals.current is not None and self.now < end:
            self.run(PERIOD)


def ended(bench: Bench) -> NavFeedback:
    return next(f for f in reversed(bench.out.feedback) if f.state.done)
