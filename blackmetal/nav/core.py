"""The navigation service's core: payloads and ``now`` in, twists, feedback and reports out. Pure and clock-injected.

It decides everything the service does: which goals to take (and the sentence for the ones it refuses), when a goal
ends and why, what to command on each pose. Its edge (``nav/zenoh_edge.py``) only routes: inputs by key to the ``on_``
methods, outputs by type to their keys (:data:`NavOutput`), and calls :meth:`NavCore.tick` at
:meth:`NavCore.next_deadline`.

A goal that ends other than by arriving (canceled, aborted) sends one zero twist, and then nothing: after an e-stop is
released, or a teleop lets go, the robot stays where it is until someone sends a new goal.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TypeVar

import msgspec

from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import (
    DriverChange,
    ErrorReport,
    GatewayHealth,
    GatewayParams,
    GoalState,
    Keys,
    MapPose,
    NavCancel,
    NavCancelReply,
    NavFeedback,
    NavGoal,
    NavGoalReply,
    NavMove,
    NavResult,
    NavResultQuery,
    ParamResult,
    ParamsSet,
    ParamsSetReply,
    PayloadError,
    PlanarPose,
    Pose,
    SetPose,
    Sources,
    Twist,
    Vector3,
    WheelMove,
    WheelMoveReply,
    WheelPosition,
    decode,
    excerpt,
)

from .controller import DEFAULT_PERIOD_S, Controller, Target, Tolerances, plan
from .goals import GoalRecord, Goals, jumped, map_to_odom, odom_to_map, out_of_bounds, placed, refusal, robot_trouble, wrap
from .params import READ_ONLY, GatewayLimits, NavParams, effective_limits
from .robot_moves import RobotConstants, RobotMoveTracker, outcome, wheel_move

#: Where the core's messages go; the edge routes each by its type (Twist: ``cmd_vel/nav``, NavFeedback:
#: ``nav/feedback``, MapPose: ``nav/map_pose``, GatewayParams: ``nav/params``, ErrorReport: ``errors``; WheelMove: a
#: get on ``wheels/move``, its answer to :meth:`NavCore.on_wheel_move_reply`).
NavOutput = Callable[[Twist | NavFeedback | MapPose | GatewayParams | ErrorReport | WheelMove], None]

#: A relative move turns at most this much (rad): two whole turns; more is a typo more often than a wish.
MAX_MOVE_ANGLE = 4 * math.pi
#: The estimated time left must fall by this much (s) to count as progress.
PROGRESS_S = 0.05
#: The pose period is estimated from the poses' stamps; gaps outside this range (s) are not a period.
PERIOD_RANGE = (0.005, 0.2)

M = TypeVar("M", bound=msgspec.Struct)


class NavCore:
    """One robot's navigation: at most one goal running, driven on the robot's poses (see the module docstring)."""

    def __init__(
        self,
        params: NavParams,
        keys: Keys,
        output: NavOutput,
        *,
        map_pose: MapPose,
        geofence: tuple[float, float, float, float] | None = None,
        wallclock: Callable[[], float] = time.time,
    ) -> None:
        params.check()
        self.keys = keys
        self.output = output
        self.wallclock = wallclock
        self.reporter = ErrorReporter("nav", output, wallclock)
        self.geofence = geofence
        self.goals = Goals()
        self._params = params
        self._gateway = GatewayLimits()
        self._limits = effective_limits(params, self._gateway)
        self._map = map_pose
        self._started = False  # the first tick publishes the map pose and the parameters
        self._controller: Controller | None = None
        self._target: tuple[float, float, float | None] | None = None  # the running goal in its own frame
        self._drove = False  # the running goal has published a twist (so it ends with a zero one)
        self._pose: Pose | None = None
        self._pose_at = -math.inf
        self._period = DEFAULT_PERIOD_S
        self._health: GatewayHealth | None = None
        self._alive: dict[str, bool] = {}
        self._driver: tuple[float, str | None] | None = None  # (gateway's stamp, source) of the latest news of who drives
        self._overridden_since: float | None = None
        self._feedback_due = math.inf
        self._progress = (math.inf, -math.inf)  # (lowest time left seen, when)
        self._recoveries = 0  # the running goal's re-plans when progress was last taken
        self._robot = RobotConstants()  # the gateway's word on the robot's own position moves (nav/move)
        self._robot_move: RobotMoveTracker | None = None  # the running goal is a move the robot's position control runs

    # ------------------------------------------------------------------------------------------------ telemetry

    def on_pose(self, payload: bytes, now: float) -> None:
        """An odometry pose: kept, and while a goal runs, the controller's twist for it published."""
        pose = self._decode(Pose, payload, self.keys.pose, now)
        if isinstance(pose, str):
            return
        last, self._pose, self._pose_at = self._pose, pose, now
        if last is not None and PERIOD_RANGE[0] <= pose.stamp - last.stamp <= PERIOD_RANGE[1]:
            self._period += 0.2 * (pose.stamp - last.stamp - self._period)
        jump = None if last is None or self.goals.current is None else jumped(last, pose, self._period)
        if jump is not None:
            self._end(GoalState.ABORTED, jump, now)
        self._check(now)
        self._step(now)

    def _step(self, now: float) -> None:
        """The running goal's twist for the latest pose (on each pose, and at once when a goal is accepted)."""
        controller, pose = self._controller, self._pose
        if self.goals.current is None or controller is None or pose is None:
            return
        self.goals.start()
        v, w = controller.step(pose.x, pose.y, pose.yaw, self._period)
        if controller.reached:
            self._end(GoalState.SUCCEEDED, "", now)
            return
        self.output(Twist(linear=Vector3(x=v), angular=Vector3(z=w)))
        self._drove = True

    def on_health(self, payload: bytes, now: float) -> None:
        """The gateway's health: an e-stop, or a control link down, aborts the running goal."""
        health = self._decode(GatewayHealth, payload, self.keys.health, now)
        if isinstance(health, str):
            return
        self._health = health
        if self._driver is None or health.stamp > self._driver[0]:
            self._driven_by(health.stamp, health.active_source, now)
        self._check(now)

    def on_driver(self, payload: bytes, now: float) -> None:
        """Who drives now: another source for longer than override_timeout aborts the running goal."""
        change = self._decode(DriverChange, payload, self.keys.driver, now)
        if not isinstance(change, str) and (self._driver is None or change.stamp >= self._driver[0]):
            self._driven_by(change.stamp, change.source, now)
            self._check(now)

    def on_gateway_params(self, payload: bytes, now: float) -> None:
        """The gateway's limits: a goal is planned within them from the next pose."""
        message = self._decode(GatewayParams, payload, self.keys.params, now)
        if isinstance(message, str):
            return
        self._robot = RobotConstants.of(message)
        gateway = GatewayLimits.of(message)
        if gateway != self._gateway:
            self._gateway = gateway
            self._limits_changed([])  # the limits in use may have changed

    def on_alive(self, role: str, alive: bool, now: float) -> None:
        """A liveliness token came or went (``gateway``, ``odometry``): the gateway gone aborts the running goal."""
        self._alive[role] = alive
        self._check(now)

    # --------------------------------------------------------------------------------------------------- queries

    def on_goal(self, payload: bytes | None, now: float) -> NavGoalReply:
        """A goal: accepted (the running one preempted) or refused with the reason, which is reported too."""
        key = self.keys.nav_goal
        goal = self._decode(NavGoal, payload, key, now)
        if isinstance(goal, str):
            return NavGoalReply(False, None, goal)
        if goal.frame != "odom" and goal.frame not in ("map", self._map.map):
            why = f"goal in another map: frame {goal.frame!r} is neither this robot's map {self._map.map!r} nor 'odom'"
            return self._refuse(key, goal.goal_id, why, payload, now)
        in_map = goal.frame != "odom"
        x, y, yaw = map_to_odom(self._map, goal.x, goal.y, goal.yaw or 0.0) if in_map else (goal.x, goal.y, goal.yaw or 0.0)
        target = Target(x, y, None if goal.yaw is None else yaw)
        return self._take(key, goal.goal_id, target, (goal.x, goal.y, goal.yaw), goal.frame, payload, now)

    def on_move(self, payload: bytes | None, now: float) -> NavGoalReply:
        """A relative move (a distance straight, or an angle on the spot), run as a goal in the odometry frame: by the
        robot's own position control where the gateway says it runs them (``position_moves``), else by the controller."""
        key = self.keys.nav_move
        move = self._decode(NavMove, payload, key, now)
        if isinstance(move, str):
            return NavGoalReply(False, None, move)
        if abs(move.angle) > MAX_MOVE_ANGLE:
            why = f"a move turns at most {MAX_MOVE_ANGLE:.4g} rad (two turns), got {move.angle:g}: send several moves for more"
            return self._refuse(key, move.goal_id, why, payload, now)
        pose = self._pose
        if pose is None:  # the rest of the robot's state is checked as for any goal
            return self._refuse(key, move.goal_id, self._robot_refusal(now) or "odometry not running", payload, now)
        if move.angle:
            target = Target(pose.x, pose.y, turn=move.angle)
            where = (pose.x, pose.y, wrap(pose.yaw + move.angle))
        else:
            x, y = pose.x + move.distance * math.cos(pose.yaw), pose.y + move.distance * math.sin(pose.yaw)
            target = Target(x, y, pose.yaw, reverse=move.distance < 0)
            where = (x, y, pose.yaw)
        by_robot = RobotMoveTracker(move, self._robot, now) if self._robot.position_moves and (move.angle or move.distance) else None
        return self._take(key, move.goal_id, target, where, "odom", payload, now, by_robot)

    def on_wheel_move_reply(self, payload: bytes, now: float) -> None:
        """The gateway's answer to the running move's ``wheels/move``: it runs (executing), or the goal is aborted."""
        reply, tracker = self._decode(WheelMoveReply, payload, self.keys.wheels_move, now), self._robot_move
        if tracker is not None and not isinstance(reply, str):
            refused = tracker.on_reply(reply, now)
            if refused is None:
                self.goals.start()
            else:
                self._end(GoalState.ABORTED, f"the gateway refused the robot's position move: {refused}", now)

    def on_wheel_position(self, payload: bytes, now: float) -> None:
        """The gateway's ``wheels/position``: the running robot move's progress, and its end."""
        position, tracker = self._decode(WheelPosition, payload, self.keys.wheels_position, now), self._robot_move
        progress = None if tracker is None or isinstance(position, str) else tracker.on_position(position, now)
        if progress is not None and (ended := outcome(progress)) is not None:
            self._end(*ended, now)

    def on_cancel(self, payload: bytes | None, now: float) -> NavCancelReply:
        """Cancel the running goal (any, or the one named): it ends canceled, the robot gets one zero twist."""
        key = self.keys.nav_cancel
        request = self._decode(NavCancel, payload, key, now, empty=NavCancel())
        if isinstance(request, str):
            return NavCancelReply([], request)
        current = self.goals.current
        if request.goal_id is None:
            if current is None:
                return NavCancelReply([], "no goal is running")
        elif current is None or current.goal_id != request.goal_id:
            known = self.goals.find(request.goal_id)
            if known is not None:
                return NavCancelReply([], f"goal {request.goal_id} is not running: it ended {known.state.value}")
            why = self.goals.unknown(request.goal_id)
            self.reporter.report(key, why, excerpt(payload or b""), now=now)
            return NavCancelReply([], why)
        assert current is not None
        self._end(GoalState.CANCELED, "canceled by a client", now)
        return NavCancelReply([current.goal_id], "")

    def on_result(self, payload: bytes | None, now: float) -> NavResult:
        """A goal's state: the one named, or the latest."""
        key = self.keys.nav_result
        query = self._decode(NavResultQuery, payload, key, now, empty=NavResultQuery())
        if isinstance(query, str):
            return NavResult(False, reason=query)
        record = self.goals.latest() if query.goal_id is None else self.goals.find(query.goal_id)
        if record is None:
            why = self.goals.unknown(query.goal_id) if query.goal_id else "no goal yet"
            return NavResult(False, query.goal_id, reason=why)
        self._update_pose(record)
        return record.result(now)

    def on_set_pose(self, payload: bytes | None, now: float) -> MapPose:
        """The robot is at the given map pose now: odom is placed on the map so that it is (PayloadError, reported, if not)."""
        key = self.keys.nav_set_pose
        try:
            request = decode(SetPose, payload or b"")
            if request.frame not in ("map", self._map.map):
                raise PayloadError("SetPose", f"set_pose takes a pose on the map {self._map.map!r}, not in frame {request.frame!r}")
            if self._pose is None:
                raise PayloadError("SetPose", "odometry not running: no pose yet to place on the map")
        except PayloadError as exc:
            self.reporter.report(key, str(exc), exc.excerpt or excerpt(payload or b""), now=now)
            raise
        pose = self._pose
        x, y, yaw = placed((request.x, request.y, request.yaw), (pose.x, pose.y, pose.yaw))
        self._map = MapPose(self.wallclock(), x, y, yaw, self._map.map, by=key)
        record, controller, target = self.goals.current, self._controller, self._target
        if record is not None and controller is not None and target is not None and record.frame != "odom":
            gx, gy, gyaw = map_to_odom(self._map, target[0], target[1], target[2] or 0.0)
            controller.retarget(Target(gx, gy, None if target[2] is None else gyaw))
        self.output(self._map)
        return self._map

    def on_params_set(self, payload: bytes | None, now: float) -> ParamsSetReply:
        """Set parameters, each on its own; the refused ones say why (and are reported)."""
        key = self.keys.nav_params_set
        request = self._decode(ParamsSet, payload, key, now)
        if isinstance(request, str):
            return ParamsSetReply([ParamResult("", False, f'{request}; send {{"values": {{"max_speed": 0.2}}}}')], self.params())
        self._params, results = self._params.with_values(request.values)
        for refused in (result.reason for result in results if not result.successful):
            self.reporter.report(key, refused, now=now)
        changed = [result.name for result in results if result.successful]
        if changed:
            if "feedback_hz" in changed and self.goals.current is not None:
                self._feedback_due = min(self._feedback_due, now + 1 / self._params.feedback_hz)
            self._limits_changed(changed)
        return ParamsSetReply(results, self.params())

    def params(self, changed: list[str] | None = None) -> GatewayParams:
        """``nav/params`` now: the live parameters, then the limits in use."""
        return GatewayParams(self.wallclock(), self._params.table(self._limits), changed or [])

    def map_pose(self) -> MapPose:
        return self._map

    # --------------------------------------------------------------------------------------------------- time

    def tick(self, now: float) -> None:
        """What time alone brings: the first publications, a stale pose or a long override (aborts), feedback, summaries."""
        if not self._started:
            self._started = True
            self.output(self._map)
            self.output(self.params())
        self._check(now)
        if self._robot_move is not None and (ended := outcome(self._robot_move.check(now))) is not None:
            self._end(*ended, now)
        if self.goals.current is not None and now >= self._feedback_due:
            self._feedback(now)
            self._feedback_due = max(self._feedback_due + 1 / self._params.feedback_hz, now + 0.5 / self._params.feedback_hz)
        self.reporter.tick(now)

    def next_deadline(self) -> float:
        if not self._started:
            return -math.inf
        due = self.reporter.next_deadline()
        if self.goals.current is not None:
            p = self._params
            due = min(due, self._feedback_due, self._pose_at + p.pose_timeout, self._progress[1] + p.no_progress_timeout)
            if self._overridden_since is not None:
                due = min(due, self._overridden_since + p.override_timeout)
            if self._robot_move is not None:
                due = min(due, self._robot_move.deadline())
        return due

    # ------------------------------------------------------------------------------------------------ internals

    def _decode(self, kind: type[M], payload: bytes | None, key: str, now: float, empty: M | None = None) -> M | str:
        """The message in ``payload`` (``empty`` for none, when given), or why it is none (reported)."""
        if empty is not None and (not payload or not payload.strip()):
            return empty
        try:
            return decode(kind, payload or b"")
        except PayloadError as exc:
            self.reporter.report(key, str(exc), exc.excerpt, now=now)
            return str(exc)

    def _refuse(self, key: str, goal_id: str | None, why: str, payload: bytes | None, now: float) -> NavGoalReply:
        self.reporter.report(key, why, excerpt(payload or b""), now=now)
        return NavGoalReply(False, goal_id, why)

    def _robot_trouble(self) -> str | None:
        """What keeps the robot from following any goal now: an e-stop, the gateway gone, its link down."""
        return robot_trouble(self._health, self._alive.get("gateway"))

    def _robot_refusal(self, now: float) -> str | None:
        """Why no goal can start now (e-stop, robot unreachable, odometry not running), if none can."""
        age = None if self._pose is None else now - self._pose_at
        return refusal(self._health, self._alive, age, self._params.pose_timeout, self.keys.estop_release)

    def _take(
        self,
        key: str,
        goal_id: str | None,
        target: Target,
        where: tuple[float, float, float | None],
        frame: str,
        payload: bytes | None,
        now: float,
        by_robot: RobotMoveTracker | None = None,
    ) -> NavGoalReply:
        """Accept ``target`` (odom) given as ``where`` in ``frame``, unless the id, the robot or the bounds refuse it;
        ``by_robot``: a move the robot's position control runs (the controller stands aside)."""
        if goal_id is not None:
            taken = self.goals.refusal_of_id(goal_id)
            if taken is not None:
                return self._refuse(key, goal_id, taken, payload, now)
        refusal = self._robot_refusal(now)
        if refusal is not None or self._pose is None:
            return self._refuse(key, goal_id, refusal or "odometry not running: no pose yet", payload, now)
        pose = self._pose
        outside = out_of_bounds(pose, (target.x, target.y), self._params.max_goal_distance, self.geofence, self._map)
        if outside is not None:
            return self._refuse(key, goal_id, outside, payload, now)
        goal_id = goal_id or self.goals.new_id()
        yaw = where[2]
        if yaw is None:  # the heading it will arrive with
            heading = pose.yaw + plan(pose.x, pose.y, pose.yaw, target, self._limits, self._tolerances()).turn
            yaw = heading if frame == "odom" else odom_to_map(self._map, 0.0, 0.0, heading)[2]
        record = GoalRecord(goal_id, PlanarPose(where[0], where[1], wrap(yaw), frame), now)
        previous = self._controller
        v, w = (previous.v, previous.w) if previous is not None and self.goals.current is not None else (0.0, 0.0)
        preempted = self.goals.accept(record, now)
        if preempted is not None:
            self._update_pose(preempted)
            self._feedback(now, preempted)
        self._controller = Controller(target, self._limits, self._tolerances(), v=v, w=w, period=self._period)
        self._target = where
        self._drove = self._drove and preempted is not None
        self._overridden_since = None if self._driver is None or self._driver[1] == Sources.NAV else now
        self._progress, self._recoveries = (math.inf, now), 0
        self._feedback_due = now
        self._robot_move = by_robot
        if by_robot is not None:  # one zero twist ends it on a cancel or an abort (the gateway ends a move on any twist)
            self._controller, self._drove = None, True
            self.output(wheel_move(by_robot.move, self._robot, goal_id))
            return NavGoalReply(True, goal_id, "")
        self._step(now)  # the first command now, from the latest pose (fresh: checked above), not a period later
        return NavGoalReply(True, goal_id, "")

    def _tolerances(self) -> Tolerances:
        return Tolerances(self._params.xy_tolerance, self._params.yaw_tolerance, self._params.reverse_distance)

    def _limits_changed(self, changed: list[str]) -> None:
        """Parameters ``changed`` (or the gateway's limits): the limits in use follow; nav/params says what changed."""
        before, self._limits = self._limits, effective_limits(self._params, self._gateway)
        changed = changed + [name for name, (field, _) in READ_ONLY.items() if getattr(before, field) != getattr(self._limits, field)]
        if self._controller is not None:
            self._controller.set_limits(self._limits, self._tolerances())
        if changed:
            self.output(self.params(changed))

    def _driven_by(self, stamp: float, source: str | None, now: float) -> None:
        self._driver = (stamp, source)
        if source == Sources.NAV:
            if self._overridden_since is not None:  # given back: what the other source did is no lack of progress
                self._progress = (math.inf, now)
            self._overridden_since = None
        elif self._overridden_since is None and self.goals.current is not None:
            self._overridden_since = now

    def _check(self, now: float) -> None:
        """Abort the running goal if the robot can no longer follow it."""
        if self.goals.current is not None:
            reason = self._abort_reason(now)
            if reason is not None:
                self._end(GoalState.ABORTED, reason, now)

    def _abort_reason(self, now: float) -> str | None:
        p = self._params
        trouble = self._robot_trouble()
        if trouble is not None:
            return trouble
        if now >= self._pose_at + p.pose_timeout:
            return f"pose stale: no pose from the odometry for {now - self._pose_at:.2f} s (pose_timeout {p.pose_timeout:g} s)"
        since = self._overridden_since
        if since is not None and now >= since + p.override_timeout:
            who = self._driver[1] if self._driver is not None else None
            by = f"{who} drives" if who is not None else "nobody drives (a lock blocks the navigation?)"
            return f"overridden: {by} instead of the navigation for {now - since:.1f} s"
        if now >= self._progress[1] + p.no_progress_timeout:
            distance, yaw, _ = self._feedback_figures()
            return f"no progress: {distance:.2f} m and {math.degrees(abs(yaw)):.1f} deg left, no closer for {now - self._progress[1]:.1f} s"
        return None

    def _end(self, state: GoalState, reason: str, now: float) -> None:
        """The running goal ends: one zero twist unless it arrived (it stood still already), the last feedback."""
        record = self.goals.current
        if record is None:
            return
        if state is not GoalState.SUCCEEDED and self._drove:
            self.output(Twist())
        self._update_pose(record)
        if self._controller is not None:
            record.recoveries = self._controller.recoveries
        self.goals.finish(state, reason, now)
        if state is GoalState.ABORTED:
            self.reporter.report(
                self.keys.nav_goal, f"goal {record.goal_id} {state.value}: {reason}", now=now, family=f"{self.keys.nav_goal}/{state.value}"
            )
        self._feedback(now, record)
        self._controller = None
        self._robot_move = None
        self._target = None
        self._drove = False
        self._overridden_since = None
        self._feedback_due = math.inf

    def _feedback_figures(self) -> tuple[float, float, float]:
        """(distance m, yaw rad, seconds) left of the running goal, from the latest pose."""
        controller, pose, tracker = self._controller, self._pose, self._robot_move
        if tracker is not None:
            left = tracker.progress
            return (0.0, left.remaining, left.eta) if tracker.move.angle else (abs(left.remaining), 0.0, left.eta)
        if controller is None or pose is None:
            return 0.0, 0.0, 0.0
        return controller.remaining(pose.x, pose.y, pose.yaw)

    def _update_pose(self, record: GoalRecord) -> None:
        """The record's pose: the robot's latest, in the goal's frame (kept as it was once the goal ended)."""
        pose = self._pose
        if pose is None or (record.state.done and record.pose is not None):
            return
        x, y, yaw = (pose.x, pose.y, pose.yaw) if record.frame == "odom" else odom_to_map(self._map, pose.x, pose.y, pose.yaw)
        record.pose = PlanarPose(x, y, wrap(yaw), record.frame)

    def _feedback(self, now: float, record: GoalRecord | None = None) -> None:
        record = record or self.goals.current
        if record is None:
            return
        self._update_pose(record)
        if record.state.done:
            self.output(record.feedback(self.wallclock(), now))
            return
        distance, _, eta = self._feedback_figures()
        if self._controller is not None:
            record.recoveries = self._controller.recoveries
        if eta < self._progress[0] - PROGRESS_S or record.recoveries != self._recoveries:  # closer, or a new plan
            self._progress, self._recoveries = (eta, now), record.recoveries  # (taken with the feedback: >= 5 Hz)
        self.output(record.feedback(self.wallclock(), now, distance, eta))
