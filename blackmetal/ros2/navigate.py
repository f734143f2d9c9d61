"""The ``navigate_to_pose`` action, ``/goal_pose``, ``/initialpose`` and ``map -> odom``, translated to the robot's
``nav/*`` keys. Pure: fed bytes and ``now``, it asks queries and writes replies and topics through the core's output.

Two surfaces share one memory of goals: the ROS node's action on rmw_zenoh's keys (``get_result`` held open until the
goal ends, as rcl_action answers it) and, with ``--rmf``, free_fleet's plain bridge keys (``get_result`` answered at
once with the status now: free_fleet reads ACCEPTED / EXECUTING as "not done" and asks again). docs/ros2-adapter.md
"Navigation" says what each call becomes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import (
    GoalState,
    Keys,
    MapPose,
    NavCancel,
    NavCancelReply,
    NavFeedback,
    NavGoal,
    NavGoalReply,
    NavResult,
    NavResultQuery,
    PayloadError,
    SetPose,
    decode,
    encode,
)

from . import action_cdr as cdr
from .action_types import ERROR_NONE, ERROR_UNKNOWN, NavLayout
from .naming import attachment
from .options import Ros2Output
from .ros_types import Transform

#: The action's service names (the node's: relative to its namespace; RMF's: under its robot name).
SEND_GOAL, CANCEL_GOAL, GET_RESULT = (
    "navigate_to_pose/_action/send_goal",
    "navigate_to_pose/_action/cancel_goal",
    "navigate_to_pose/_action/get_result",
)
ACTION_SERVICES = (SEND_GOAL, CANCEL_GOAL, GET_RESULT)
RMF = "rmf/"  # the RMF surface's services and topics: "rmf/" + the name
FEEDBACK, STATUS = "navigate_to_pose/_action/feedback", "navigate_to_pose/_action/status"
RMF_TF, RMF_BATTERY = RMF + "tf", RMF + "battery_state"

#: action_msgs/GoalStatus.
UNKNOWN, ACCEPTED, EXECUTING, CANCELING, SUCCEEDED, CANCELED, ABORTED = range(7)
STATUS_OF = {
    GoalState.ACCEPTED: ACCEPTED,
    GoalState.EXECUTING: EXECUTING,
    GoalState.SUCCEEDED: SUCCEEDED,
    GoalState.CANCELED: CANCELED,
    GoalState.ABORTED: ABORTED,
}
TERMINAL = (SUCCEEDED, CANCELED, ABORTED)
#: action_msgs/CancelGoal_Response return codes.
CANCEL_OK, CANCEL_REJECTED, CANCEL_UNKNOWN_GOAL, CANCEL_TERMINATED = range(4)
#: Goals remembered for status and results (the oldest finished one is forgotten first).
MAX_GOALS = 32
#: get_result calls held open at once; one more is answered with its goal's state now.
MAX_WAITING = 64
#: While a get_result waits, nav/result is asked this often (s), in case the goal's last feedback was missed.
RESULT_POLL_S = 1.0
#: Polls of a held goal in a row that nobody answers before it ends ABORTED.
UNANSWERED_POLLS = 3
#: The action's queries of the navigation service outstanding at once; a call beyond them is refused at once.
MAX_ASKING = 256
#: How long the adapter waits for the navigation service to answer (s).
NAV_TIMEOUT_S = 2.0
BATTERY_PERIOD_S = 1.0


def hex_of(uuid: bytes) -> str:
    return uuid.hex()


def _uuid(goal_id: str) -> bytes:
    """A goal id of the navigation service as a UUID's 16 bytes (an id not 32 hex digits: empty)."""
    try:
        uuid = bytes.fromhex(goal_id)
    except ValueError:
        return b""
    return uuid if len(uuid) == cdr.UUID_SIZE else b""


@dataclass(slots=True)
class Goal:
    uuid: bytes
    sec: int  # when accepted (wall clock)
    nanosec: int
    status: int = ACCEPTED
    reason: str = ""
    #: When to ask the service how it ended, if no feedback has said so (a goal preempted by a newer one).
    check_at: float = math.inf
    #: Polls of nav/result in a row nobody answered.
    unanswered: int = 0

    @property
    def info(self) -> cdr.GoalInfo:
        return self.uuid, self.sec, self.nanosec


@dataclass(slots=True)
class Waiting:
    """A call waiting: for the navigation service's answer (``what``), or a get_result for its goal to end."""

    what: str
    call: int
    reply_to: tuple[int, bytes] | None
    uuid: bytes = cdr.ZERO_UUID
    surface: str = ""  # "" the node's, RMF for free_fleet's


class NavAction:
    """See the module docstring. ``odom_frame``: the node's odometry frame (``r1/odom`` in a fleet), which goals may name."""

    def __init__(
        self,
        keys: Keys,
        output: Ros2Output,
        reporter: ErrorReporter,
        wallclock: Callable[[], float],
        layout: NavLayout,
        odom_frame: str,
        rmf: bool = False,
        battery: Callable[[], bytes] | None = None,
    ) -> None:
        """``battery``: RMF's sensor_msgs/BatteryState now, published each second (None: no battery is known)."""
        self.keys, self.output, self.reporter, self.wallclock = keys, output, reporter, wallclock
        self.layout, self.odom_frame, self.rmf, self.battery = layout, odom_frame, rmf, battery
        self.goals: dict[bytes, Goal] = {}
        self.queries: dict[int, Waiting] = {}  # by (negative) tag
        self.results: dict[int, Waiting] = {}  # get_result calls held open, by call
        self.map_pose: MapPose | None = None
        #: Whether someone subscribes to a topic (the core's matching listeners say): feedback nobody reads is not encoded.
        self.wants: Callable[[str], bool] = lambda topic: True
        #: How a bad ROS request is reported (the core's: counted in /diagnostics as a rejected input too).
        self.reject: Callable[[str, str, str, float], None] = lambda key, reason, excerpt, now: reporter.report(
            key, reason, excerpt, now=now
        )
        self._tag = 0
        self._next_poll = math.inf
        self._next_check = math.inf  # the earliest Goal.check_at
        self._next_battery = -math.inf if rmf and battery is not None else math.inf

    # --- the robot's side -------------------------------------------------------------------------------------
    def start(self) -> None:
        self._ask("map_pose", self.keys.nav_map_pose, None, Waiting("map_pose", 0, None), now=-math.inf)

    def on_map_pose(self, payload: bytes, now: float) -> None:
        try:
            self.map_pose = decode(MapPose, payload)
        except PayloadError as exc:
            self.reporter.report(self.keys.nav_map_pose, str(exc), exc.excerpt, now=now)

    def map_transform(self, odom_frame: str) -> Transform | None:
        """``map -> odom`` as the navigation service places it, for /tf; None until it has said."""
        m = self.map_pose
        if m is None:
            return None
        return Transform(m.map, odom_frame, (m.x, m.y, 0.0), (0.0, 0.0, math.sin(m.yaw / 2), math.cos(m.yaw / 2)))

    def on_alive(self, alive: bool, now: float) -> None:
        """The navigation service's liveliness token: gone, no goal of it can go on; each ends ABORTED, held results
        answered (rmw_zenoh's get_result waits for ever otherwise). Back: its map frame asked again."""
        if alive:
            return self._ask("map_pose", self.keys.nav_map_pose, None, Waiting("map_pose", 0, None), now)
        reason = f"the navigation service on {self.keys.prefix} went away ({self.keys.alive_nav} is gone): the goal cannot go on"
        for goal in [g for g in self.goals.values() if g.status not in TERMINAL]:
            self._set(goal, ABORTED, reason)

    def on_feedback(self, payload: bytes, now: float) -> None:
        """A goal's progress: its feedback out while it runs, its status on each change, its waiting results answered."""
        try:
            f = decode(NavFeedback, payload)
            uuid = bytes.fromhex(f.goal_id)
            if len(uuid) != cdr.UUID_SIZE:
                raise ValueError
        except (PayloadError, ValueError) as exc:
            return self.reporter.report(
                self.keys.nav_feedback, f"not a navigation feedback with a 32-hex-digit goal id: {exc}", "", now=now
            )
        goal = self.goals.get(uuid) or self._remember(uuid, f.stamp - f.elapsed)
        status = STATUS_OF[f.state]
        if status not in TERMINAL and (self.wants(FEEDBACK) or (self.rmf and self.wants(RMF + FEEDBACK))):
            frame = self.odom_frame if f.pose.frame == "odom" else f.pose.frame
            sec, nanosec = cdr.duration(f.stamp)
            values = cdr.Feedback(sec, nanosec, frame, f.pose.x, f.pose.y, f.pose.yaw, f.elapsed, f.eta, f.recoveries, f.distance_remaining)
            if self.wants(FEEDBACK):
                self.output.ros(FEEDBACK, cdr.feedback_message(self.layout, uuid, values))
            if self.rmf and self.wants(RMF + FEEDBACK):  # free_fleet: the frame as the service names it, Jazzy's layout
                self.output.ros(RMF + FEEDBACK, cdr.feedback_message(NavLayout.JAZZY, uuid, replace(values, frame=f.pose.frame)))
        if goal.status == CANCELING and status in (ACCEPTED, EXECUTING):
            status = CANCELING  # a cancel was asked: CANCELING until the service says how the goal ended
        self._set(goal, status, f.reason)

    def _remember(self, uuid: bytes, stamp: float) -> Goal:
        sec, nanosec = cdr.duration(stamp)
        goal = self.goals[uuid] = Goal(uuid, sec, nanosec)
        while len(self.goals) > MAX_GOALS:
            oldest = next((g for g in self.goals.values() if g.status in TERMINAL), next(iter(self.goals.values())))
            del self.goals[oldest.uuid]
        return goal

    def _set(self, goal: Goal, status: int, reason: str) -> None:
        if status == goal.status and reason == goal.reason:
            return
        goal.status, goal.reason = status, reason
        self._publish_status()
        if status in TERMINAL:
            for waiting in [w for w in self.results.values() if w.uuid == goal.uuid]:
                self._answer_result(waiting, goal)

    def _publish_status(self) -> None:
        message = cdr.status_array([(g.info, g.status) for g in self.goals.values()])
        self.output.ros(STATUS, message)
        if self.rmf:
            self.output.ros(RMF + STATUS, message)

    # --- calls ------------------------------------------------------------------------------------------------
    def on_request(self, service: str, call: int, payload: bytes, reply_to: tuple[int, bytes] | None, now: float) -> None:
        surface = RMF if service.startswith(RMF) else ""
        name = service.removeprefix(RMF)
        waiting = Waiting(name, call, reply_to, surface=surface)
        try:
            if name == SEND_GOAL:
                return self._send_goal(waiting, *cdr.send_goal_request(payload), now=now)
            if name == CANCEL_GOAL:
                return self._cancel(waiting, *cdr.cancel_goal_request(payload), now=now)
            if name == GET_RESULT:
                return self._get_result(waiting, cdr.get_result_request(payload), now)
        except PayloadError as exc:  # answered all the same: rmw_zenoh's client drops an error reply and waits for ever
            self.reject(service, str(exc), exc.excerpt, now)
            return self._refuse(waiting)
        self.output.service_refuse(call, f"no service {service!r} here")

    def _refuse(self, waiting: Waiting) -> None:
        """The answer that refuses a call without reading it: not accepted, nothing canceled, the result UNKNOWN."""
        if waiting.what == SEND_GOAL:
            self._reply(waiting, cdr.send_goal_response(False, *cdr.duration(self.wallclock())))
        elif waiting.what == CANCEL_GOAL:
            self._reply(waiting, cdr.cancel_goal_response(CANCEL_REJECTED, []))
        else:
            self._answer_result(waiting, None)

    def _frame(self, frame: str) -> str | None:
        """A ROS frame as the navigation service names it: ``map`` or ``odom``; None for any other."""
        map_frame = self.map_pose.map if self.map_pose is not None else "map"
        if frame in ("", "map", map_frame):
            return "map"
        if frame in ("odom", self.odom_frame):
            return "odom"
        return None

    def _send_goal(self, waiting: Waiting, uuid: bytes, pose: cdr.StampedPose, tree: str, now: float) -> None:
        waiting.uuid = uuid
        frame = self._frame(pose.frame)
        if frame is None:
            reason = f"goal in frame {pose.frame!r}: give map or {self.odom_frame} (the robot has no other frame to navigate in)"
            self.reporter.report(waiting.what, reason, "", now=now)
            return self._reply(waiting, cdr.send_goal_response(False, *cdr.duration(self.wallclock())))
        goal = NavGoal(x=pose.x, y=pose.y, yaw=pose.yaw, frame=frame, goal_id=hex_of(uuid))
        self._ask("goal", self.keys.nav_goal, encode(goal), waiting, now)

    def _cancel(self, waiting: Waiting, uuid: bytes, sec: int, nanosec: int, now: float) -> None:
        waiting.uuid = uuid
        if uuid != cdr.ZERO_UUID:
            asked = NavCancel(goal_id=hex_of(uuid))
        elif sec or nanosec:  # the goals accepted at or before the stamp: the one running, if it was
            running = [g for g in self.goals.values() if g.status not in TERMINAL and (g.sec, g.nanosec) <= (sec, nanosec)]
            if not running:
                return self._reply(waiting, cdr.cancel_goal_response(CANCEL_REJECTED, []))
            asked = NavCancel(goal_id=hex_of(running[-1].uuid))
        else:
            asked = NavCancel()
        self._ask("cancel", self.keys.nav_cancel, encode(asked), waiting, now)

    def _get_result(self, waiting: Waiting, uuid: bytes, now: float) -> None:
        waiting.uuid = uuid
        goal = self.goals.get(uuid)
        if goal is not None and (goal.status in TERMINAL or waiting.surface == RMF):
            return self._answer_result(waiting, goal)
        if goal is not None:
            return self._hold(waiting, now)
        self._ask("result", self.keys.nav_result, encode(NavResultQuery(goal_id=hex_of(uuid))), waiting, now)

    def _hold(self, waiting: Waiting, now: float) -> None:
        if len(self.results) >= MAX_WAITING:  # answered with the state now, as free_fleet's are: a reply, not an error
            self.reporter.report(
                waiting.what, f"{MAX_WAITING} get_result calls already wait for their goal: answered with its state now", now=now
            )
            return self._answer_result(waiting, self.goals.get(waiting.uuid))
        self.results[waiting.call] = waiting
        self._next_poll = min(self._next_poll, now + RESULT_POLL_S)

    def _answer_result(self, waiting: Waiting, goal: Goal | None) -> None:
        self.results.pop(waiting.call, None)
        layout = NavLayout.JAZZY if waiting.surface == RMF else self.layout
        if goal is None:
            return self._reply(waiting, cdr.get_result_response(layout, UNKNOWN))
        code = ERROR_UNKNOWN if goal.status == ABORTED else ERROR_NONE
        self._reply(waiting, cdr.get_result_response(layout, goal.status, code, goal.reason if goal.status in TERMINAL else ""))

    def _reply(self, waiting: Waiting, response: bytes) -> None:
        extra = None
        if waiting.reply_to is not None:
            sequence, gid = waiting.reply_to
            extra = attachment(sequence, round(self.wallclock() * 1e9), gid)
        self.output.service_reply(waiting.call, response, extra)

    # --- the navigation service's answers ---------------------------------------------------------------------
    def _ask(self, what: str, key: str, payload: bytes | None, waiting: Waiting, now: float) -> None:
        if len(self.queries) >= MAX_ASKING:
            if waiting.call or waiting.what in ("pose", "set_pose"):  # a client's request: refused, and said why
                reason = f"{MAX_ASKING} requests already wait for the navigation service on {self.keys.prefix}/nav: refused, ask again"
                self.reporter.report(key, reason, "", now=now)
            if waiting.call:
                self._refuse(waiting)
            return
        self._tag -= 1  # negative: the core's other queries are numbered from 1 up
        waiting.what = what
        self.queries[self._tag] = waiting
        self.output.query(key, payload, self._tag, NAV_TIMEOUT_S)

    def on_query_reply(self, tag: int, ok: bool, payload: bytes, now: float) -> None:
        waiting = self.queries.pop(tag, None)
        if waiting is None:
            return
        key = {"goal": self.keys.nav_goal, "cancel": self.keys.nav_cancel, "result": self.keys.nav_result}.get(
            waiting.what, self.keys.nav_map_pose
        )
        if waiting.what == "set_pose":
            key = self.keys.nav_set_pose
        if not ok:
            return self._failed(waiting, f"the navigation service refused on {key}: {payload.decode(errors='replace')}", now)
        try:
            if waiting.what in ("map_pose", "set_pose"):
                self.map_pose = decode(MapPose, payload)
            elif waiting.what in ("goal", "pose"):
                self._on_goal_reply(waiting, decode(NavGoalReply, payload), now)
            elif waiting.what == "cancel":
                self._on_cancel_reply(waiting, decode(NavCancelReply, payload))
            elif waiting.what in ("result", "poll"):
                self._on_result(waiting, decode(NavResult, payload), now)
        except PayloadError as exc:
            self._failed(waiting, f"the navigation service answered something unexpected on {key}: {exc}", now)

    def on_query_done(self, tag: int, now: float) -> None:
        """No reply came (the query is still ours): nobody serves the key. A held get_result's goal asked this many
        times in a row with no answer ends ABORTED (a navigation gone without its liveliness token saying so)."""
        waiting = self.queries.pop(tag, None)
        if waiting is not None and waiting.what == "poll":
            goal = self.goals.get(waiting.uuid)
            if goal is not None and goal.status not in TERMINAL:
                goal.unanswered += 1
                if goal.unanswered >= UNANSWERED_POLLS:
                    self._set(goal, ABORTED, f"no navigation service answered on {self.keys.nav_result} for {goal.unanswered} polls")
            return
        if waiting is not None and waiting.what != "map_pose":
            self._failed(
                waiting, f"no navigation service answered on {self.keys.prefix}/nav (is blackmetal nav running for this robot?)", now
            )

    def _failed(self, waiting: Waiting, reason: str, now: float) -> None:
        if waiting.what == "poll":
            return
        self.reporter.report(self.keys.nav_goal if waiting.what in ("goal", "pose") else self.keys.prefix + "/nav", reason, "", now=now)
        if waiting.what == "goal":
            self._reply(waiting, cdr.send_goal_response(False, *cdr.duration(self.wallclock())))
        elif waiting.what == "cancel":
            self._reply(waiting, cdr.cancel_goal_response(CANCEL_REJECTED, []))
        elif waiting.what == "result":  # nobody could say: UNKNOWN, as rcl_action answers an id it does not know
            self._answer_result(waiting, None)

    def _on_goal_reply(self, waiting: Waiting, reply: NavGoalReply, now: float) -> None:
        # a refusal's sentence is the navigation service's to report (on <prefix>/errors): said once, not twice
        if waiting.what == "pose":
            return
        stamp = self.wallclock()
        if reply.accepted:
            if waiting.uuid not in self.goals:
                self._remember(waiting.uuid, stamp)
            self._publish_status()
            for other in [g for g in self.goals.values() if g.uuid != waiting.uuid and g.status not in TERMINAL]:
                other.check_at = min(other.check_at, now + RESULT_POLL_S)  # preempted: asked, should its last feedback be missed
                self._next_check = min(self._next_check, other.check_at)
        self._reply(waiting, cdr.send_goal_response(reply.accepted, *cdr.duration(stamp)))

    def _on_cancel_reply(self, waiting: Waiting, reply: NavCancelReply) -> None:
        canceling: list[cdr.GoalInfo] = []
        for goal_id in reply.canceled:
            uuid = _uuid(goal_id)
            goal = self.goals.get(uuid)
            if goal is not None and goal.status not in TERMINAL:
                goal.status = CANCELING
            canceling.append(goal.info if goal is not None else (uuid or cdr.ZERO_UUID, 0, 0))
        if canceling:
            self._publish_status()
            return self._reply(waiting, cdr.cancel_goal_response(CANCEL_OK, canceling))
        known = self.goals.get(waiting.uuid)
        if waiting.uuid == cdr.ZERO_UUID:
            code = CANCEL_REJECTED
        else:
            code = CANCEL_UNKNOWN_GOAL if known is None else CANCEL_TERMINATED if known.status in TERMINAL else CANCEL_REJECTED
        self._reply(waiting, cdr.cancel_goal_response(code, []))

    def _on_result(self, waiting: Waiting, result: NavResult, now: float) -> None:
        if not result.found or result.state is None:  # the service forgot it (or never knew): UNKNOWN, as rcl_action says
            for held in [w for w in self.results.values() if w.uuid == waiting.uuid]:
                self._answer_result(held, None)
            if waiting.what == "result":
                self._answer_result(waiting, None)
            return
        goal = self.goals.get(waiting.uuid) or self._remember(waiting.uuid, self.wallclock() - result.elapsed)
        goal.unanswered = 0
        status = STATUS_OF[result.state]
        self._set(goal, CANCELING if goal.status == CANCELING and status not in TERMINAL else status, result.reason)
        if waiting.what == "result":
            if status in TERMINAL or waiting.surface == RMF:
                self._answer_result(waiting, goal)
            else:
                self._hold(waiting, now)

    # --- topics -----------------------------------------------------------------------------------------------
    def on_goal_pose(self, pose: cdr.StampedPose, now: float) -> None:
        """RViz's 2D Goal Pose: a goal the navigation service names (its refusal reported)."""
        frame = self._frame(pose.frame)
        if frame is None:
            return self.reporter.report("goal_pose", f"goal in frame {pose.frame!r}: give map or {self.odom_frame}", "", now=now)
        goal = NavGoal(x=pose.x, y=pose.y, yaw=pose.yaw, frame=frame)
        self._ask("pose", self.keys.nav_goal, encode(goal), Waiting("pose", 0, None), now)

    def on_initial_pose(self, pose: cdr.StampedPose, now: float) -> None:
        """RViz's 2D Pose Estimate: the robot is here on the map now."""
        if self._frame(pose.frame) != "map":
            return self.reporter.report("initialpose", f"initial pose in frame {pose.frame!r}: give it on the map (map)", "", now=now)
        here = SetPose(x=pose.x, y=pose.y, yaw=pose.yaw or 0.0)
        self._ask("set_pose", self.keys.nav_set_pose, encode(here), Waiting("set_pose", 0, None), now)

    def tick(self, now: float) -> None:
        if now >= self._next_check:
            for goal in [g for g in self.goals.values() if g.check_at <= now]:
                goal.check_at = math.inf
                if goal.status not in TERMINAL:
                    self._poll(goal.uuid, now)
            self._next_check = min((g.check_at for g in self.goals.values()), default=math.inf)
        if now >= self._next_poll:
            self._next_poll = now + RESULT_POLL_S if self.results else math.inf
            for uuid in dict.fromkeys(w.uuid for w in self.results.values()):
                self._poll(uuid, now)
        if now >= self._next_battery and self.battery is not None:
            self._next_battery = now + BATTERY_PERIOD_S
            self.output.ros(RMF_BATTERY, self.battery())

    def _poll(self, uuid: bytes, now: float) -> None:
        self._ask("poll", self.keys.nav_result, encode(NavResultQuery(goal_id=hex_of(uuid))), Waiting("poll", 0, None, uuid), now)

    def next_deadline(self) -> float:
        return min(self._next_poll, self._next_battery, self._next_check)
