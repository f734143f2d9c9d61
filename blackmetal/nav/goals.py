"""Goals' lives: accepted, executing, then succeeded, canceled or aborted; one at a time; the last ones remembered.

A new goal preempts the running one, which ends canceled with "preempted by goal <id>" (ROS 2's action servers do the
same), so a client that sends a flood of goals ends up with the last one running and every other one accounted for.
The results of the last :data:`KEEP_RESULTS` goals answer ``nav/result``; a goal id is never reused while remembered,
so a late ``result`` or ``cancel`` cannot reach a different goal by the same name.

Also here: what keeps a goal from starting or running (the sentences of refusals and aborts that the robot's state
causes), and the map frame's arithmetic (``map -> odom`` is a planar transform; goals, feedback and set-pose use it).
"""

from __future__ import annotations

import math
import uuid
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

from blackmetal.schemas import GatewayHealth, GoalState, MapPose, NavFeedback, NavResult, PlanarPose, Pose

#: How many goals' results ``nav/result`` answers for (the oldest ended ones are forgotten first).
KEEP_RESULTS = 100


@dataclass(eq=False, slots=True)
class GoalRecord:
    """One goal: where to (in the frame the client used), and how it is doing or how it ended.

    ``goal.yaw`` is the heading the robot arrives with when the client gave none.
    """

    goal_id: str
    goal: PlanarPose
    accepted_at: float
    state: GoalState = GoalState.ACCEPTED
    reason: str = ""
    ended_at: float | None = None
    #: The robot's latest pose in the goal's frame (None until one is seen).
    pose: PlanarPose | None = None
    #: Times the controller stopped outside the tolerances and planned again.
    recoveries: int = 0

    @property
    def frame(self) -> str:
        return self.goal.frame

    def elapsed(self, now: float) -> float:
        """Seconds since it was accepted (until it ended, once it has)."""
        return max((self.ended_at if self.ended_at is not None else now) - self.accepted_at, 0.0)

    def feedback(self, stamp: float, now: float, distance: float | None = None, eta: float = 0.0) -> NavFeedback:
        """Its ``nav/feedback``; ``distance`` left (None: from its pose, as when it ended)."""
        pose = self.pose or self.goal
        if distance is None:
            distance = math.hypot(self.goal.x - pose.x, self.goal.y - pose.y)
        return NavFeedback(stamp, self.goal_id, self.state, pose, self.goal, distance, eta, self.elapsed(now), self.recoveries, self.reason)

    def result(self, now: float) -> NavResult:
        return NavResult(True, self.goal_id, self.state, self.reason, self.pose, self.goal, self.elapsed(now))


class Goals:
    """The running goal (at most one) and the remembered ones. ``new_id`` makes ids for goals sent without one."""

    def __init__(self, keep: int = KEEP_RESULTS, new_id: Callable[[], str] = lambda: uuid.uuid4().hex) -> None:
        self.keep = keep
        self._new_id = new_id
        self._records: OrderedDict[str, GoalRecord] = OrderedDict()  # oldest first; the running one is the newest
        self.current: GoalRecord | None = None

    def find(self, goal_id: str) -> GoalRecord | None:
        return self._records.get(goal_id)

    def latest(self) -> GoalRecord | None:
        return next(reversed(self._records.values()), None)

    def __len__(self) -> int:
        return len(self._records)

    def new_id(self) -> str:
        """A fresh id (32 hex digits) that no remembered goal has."""
        while True:
            goal_id = self._new_id()
            if goal_id not in self._records:
                return goal_id

    def unknown(self, goal_id: str) -> str:
        """The sentence for an id this book does not hold (a cancel's, a result's)."""
        return f"no goal {goal_id}: the navigation knows its last {self.keep} goals only"

    def refusal_of_id(self, goal_id: str) -> str | None:
        """Why ``goal_id`` cannot name a new goal, if it cannot."""
        known = self._records.get(goal_id)
        if known is None:
            return None
        how = "is running" if not known.state.done else f"ended {known.state.value}"
        return f"goal id {goal_id} is taken by an earlier goal that {how}: send a new id, or none to have one made"

    def accept(self, record: GoalRecord, now: float) -> GoalRecord | None:
        """``record`` becomes the running goal; the one it preempts (ended canceled) is returned."""
        if record.goal_id in self._records:
            raise ValueError(f"goal id {record.goal_id} is already known")
        if record.state is not GoalState.ACCEPTED:
            raise ValueError(f"a new goal must be accepted, not {record.state.value}")
        preempted = None
        if self.current is not None:
            preempted = self.finish(GoalState.CANCELED, f"preempted by goal {record.goal_id}", now)
        self._records[record.goal_id] = record
        self.current = record
        self._forget()
        return preempted

    def start(self) -> GoalRecord:
        """The running goal moves from accepted to executing (its first command)."""
        record = self._running()
        if record.state is GoalState.ACCEPTED:
            record.state = GoalState.EXECUTING
        return record

    def finish(self, state: GoalState, reason: str, now: float) -> GoalRecord:
        """The running goal ends in ``state`` (succeeded, canceled, aborted), with ``reason``."""
        if not state.done:
            raise ValueError(f"a goal ends succeeded, canceled or aborted, not {state.value}")
        record = self._running()
        record.state, record.reason, record.ended_at = state, reason, now
        self.current = None
        return record

    def _running(self) -> GoalRecord:
        if self.current is None:
            raise ValueError("no goal is running")
        return self.current

    def _forget(self) -> None:
        """Keep at most ``keep`` goals: the oldest ended ones go first (the running one always stays)."""
        while len(self._records) > self.keep:
            oldest = next(iter(self._records))
            if self._records[oldest] is self.current:
                break
            del self._records[oldest]


# ----------------------------------------------------------------------------------- what keeps a goal from running


def robot_trouble(health: GatewayHealth | None, gateway_alive: bool | None) -> str | None:
    """What keeps the robot from following any goal now (an e-stop, the gateway gone, its control link down): the
    reason a running goal is aborted with. ``health`` None: none heard yet (no trouble known); ``gateway_alive`` None:
    its liveliness not heard of yet."""
    if health is not None and health.estop:
        return f"e-stop engaged{health.estop_origin()}"
    if gateway_alive is False:
        return "robot unreachable: the gateway is gone (its liveliness token went away)"
    if health is not None and health.control.state != "connected":
        why = f": {health.control.reason}" if health.control.reason else ""
        return f"robot unreachable: the gateway's control link is {health.control.state}{why}"
    return None


def refusal(
    health: GatewayHealth | None, alive: dict[str, bool], pose_age: float | None, pose_timeout: float, release_key: str
) -> str | None:
    """Why a new goal is refused, if it is: the robot e-stopped or unreachable (no health heard counts), or the odometry
    not running (no pose, or the last one ``pose_age`` seconds old)."""
    trouble = robot_trouble(health, alive.get("gateway"))
    if trouble is not None and trouble.startswith("e-stop"):
        return f"robot is e-stopped ({trouble}): release it on {release_key}, then send the goal again"
    if trouble is not None or health is None:
        return trouble or "robot unreachable: no health report from the gateway yet"
    if pose_age is None:
        return "odometry not running: no pose received yet"
    if pose_age > pose_timeout:
        gone = " (its liveliness token is gone)" if alive.get("odometry") is False else ""
        return f"odometry not running: the last pose is {pose_age:.1f} s old (pose_timeout {pose_timeout:g} s){gone}"
    return None


#: Faster than this no pose moves (m/s, rad/s: the robot's wire limit of 1 m/s a wheel), plus a margin for jitter (m, rad).
JUMP_SPEED, JUMP_TURN, JUMP_MARGIN = 1.0, 4.0, 0.05


def out_of_bounds(
    pose: Pose, target: tuple[float, float], max_distance: float, geofence: tuple[float, float, float, float] | None, map_pose: MapPose
) -> str | None:
    """Why a goal at ``target`` (odom) is out of bounds: farther than ``max_distance`` from ``pose``, or outside the
    ``geofence`` (map frame); None when it is within them."""
    distance = math.hypot(target[0] - pose.x, target[1] - pose.y)
    if not distance <= max_distance:  # NaN too: a goal near the float limits, turned onto odom
        return f"goal is {distance:.1f} m from the robot, farther than max_goal_distance ({max_distance:g} m)"
    if geofence is not None:
        mx, my, _ = odom_to_map(map_pose, target[0], target[1], 0.0)
        x_min, y_min, x_max, y_max = geofence
        if not (x_min <= mx <= x_max and y_min <= my <= y_max):
            return f"goal ({mx:.2f}, {my:.2f}) on the map is outside the geofence x {x_min:g}..{x_max:g}, y {y_min:g}..{y_max:g}"
    return None


def jumped(last: Pose, pose: Pose, period: float) -> str | None:
    """Why ``pose`` cannot follow ``last`` by motion, if it cannot: the odometry was reset (or is broken), and a goal's
    place in the odometry frame means nothing any more."""
    gap = pose.stamp - last.stamp if 0 < pose.stamp - last.stamp <= 1.0 else period
    moved, turned = math.hypot(pose.x - last.x, pose.y - last.y), abs(wrap(pose.yaw - last.yaw))
    if moved <= JUMP_SPEED * gap + JUMP_MARGIN and turned <= JUMP_TURN * gap + JUMP_MARGIN:
        return None
    return f"odometry jumped {moved:.2f} m and {math.degrees(turned):.0f} deg in {gap:.2f} s (reset?): the goal's place in it is lost"


# ------------------------------------------------------------------------------------------ the map frame's arithmetic


def wrap(angle: float) -> float:
    return math.remainder(angle, math.tau)


def odom_to_map(map_pose: MapPose, x: float, y: float, yaw: float) -> tuple[float, float, float]:
    """A pose in the odometry frame, on the map (``map_pose``: where odom sits on the map)."""
    c, s = math.cos(map_pose.yaw), math.sin(map_pose.yaw)
    return map_pose.x + c * x - s * y, map_pose.y + s * x + c * y, wrap(yaw + map_pose.yaw)


def map_to_odom(map_pose: MapPose, x: float, y: float, yaw: float) -> tuple[float, float, float]:
    """A pose on the map, in the odometry frame."""
    c, s = math.cos(map_pose.yaw), math.sin(map_pose.yaw)
    dx, dy = x - map_pose.x, y - map_pose.y
    return c * dx + s * dy, -s * dx + c * dy, wrap(yaw - map_pose.yaw)


def placed(at: tuple[float, float, float], odom: tuple[float, float, float]) -> tuple[float, float, float]:
    """Where odom sits on the map when the robot, at ``odom`` in the odometry frame, is at ``at`` on the map:
    ``at`` composed with the inverse of ``odom``."""
    yaw = wrap(at[2] - odom[2])
    c, s = math.cos(yaw), math.sin(yaw)
    return at[0] - (c * odom[0] - s * odom[1]), at[1] - (s * odom[0] + c * odom[1]), yaw
