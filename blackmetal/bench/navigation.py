"""``blackmetal bench --only nav_goals,nav_fleet``: goals reached, how close and how fast, and what navigation costs.

``nav_goals`` sends one robot of ``blackmetal up`` 20 goals one after the other (turns on the spot, goals behind it,
1 cm away, 10 m away) and reads where it stopped in the odometry frame and in the simulator's truth, and how long each
took against the time a trapezoidal profile needs under the same limits (turn to the goal, drive, turn to the yaw).
``nav_fleet`` sends every robot of ``up --robots N`` a goal at once and reads the gateways' poll rate and the
navigation process's CPU while they drive.
"""

from __future__ import annotations

import math
import statistics
import tempfile
import threading
import time
from contextlib import ExitStack
from functools import partial
from pathlib import Path
from typing import Any

from blackmetal import robot_model as model
from blackmetal.schemas import (
    GatewayHealth,
    GatewayParams,
    GoalState,
    Keys,
    NavFeedback,
    NavGoal,
    NavGoalReply,
    NavResult,
    NavResultQuery,
    ParamsSet,
    ParamsSetReply,
    Pose,
    decode,
    encode,
)

from .peers import free_port
from .rig import cpu_window, service
from .rig import session as client_session
from .runner import Figure, Plan, Result, Row, met

#: The goals of ``nav_goals`` (odometry frame, relative to where the robot is when each is sent): (forward, left,
#: turn) with turn None for "any heading". Turns on the spot, goals behind, beside, 1 cm away, far away.
GOALS: tuple[tuple[float, float, float | None], ...] = (
    (0.0, 0.0, math.pi / 2),
    (0.0, 0.0, -math.pi),
    (0.0, 0.0, 0.1),
    (1.0, 0.0, 0.0),
    (-1.0, 0.0, 0.0),
    (-0.5, 0.5, None),
    (0.01, 0.0, 0.0),
    (0.0, 0.01, 0.0),
    (-0.01, 0.0, 0.0),
    (2.0, -1.0, math.pi / 2),
    (0.5, 0.5, -math.pi / 2),
    (0.0, 1.0, 0.0),
    (-1.5, -1.5, math.pi),
    (0.3, 0.0, None),
    (10.0, 0.0, 0.0),
    (-2.0, 0.3, 0.5),
    (0.05, -0.05, 0.0),
    (1.0, 1.0, math.pi / 4),
    (-0.2, 0.0, math.pi / 2),
    (3.0, 2.0, -2.0),
)
#: The bars of the issue: within these of the goal, in at most this many times the trapezoidal profile's time.
POSITION_BAR_M = 0.02
YAW_BAR_RAD = math.radians(2.0)
TIME_BAR = 1.25
#: ``nav_goals_calibrated``: a simulated robot unlike its drawing (wheels 1.5 % long and 1 % short, 2 cm wider), and
#: the constants a calibration finds for it given to every service (the simulator's truth is the drawing's error).
UNLIKE = {"left_wheel_scale": 1.015, "right_wheel_scale": 0.99, "wheel_separation": model.WHEEL_SEPARATION + 0.02}
#: One goal of ``nav_fleet`` for every robot: 1 m ahead, 0.5 m to the left, facing left.
FLEET_GOAL = (1.0, 0.5, math.pi / 2)


def trapezoid_time(distance: float, top: float, accel: float) -> float:
    """Seconds to cover ``distance`` from rest to rest at ``top`` speed and ``accel`` (a triangle when it is short)."""
    distance = abs(distance)
    if accel <= 0:
        return distance / top
    if distance < top * top / accel:
        return 2.0 * math.sqrt(distance / accel)
    return distance / top + top / accel


def reference_time(start: tuple[float, float, float], goal: tuple[float, float, float | None], limits: dict[str, float]) -> float:
    """A trapezoidal profile's time from ``start`` to ``goal`` (odometry frame): turn to face it, drive, turn to its yaw."""
    dx, dy = goal[0] - start[0], goal[1] - start[1]
    distance = math.hypot(dx, dy)
    heading = start[2]
    total = 0.0
    if distance > limits["xy_tolerance"]:
        bearing = math.atan2(dy, dx)
        total += trapezoid_time(math.remainder(bearing - heading, math.tau), limits["max_turn"], limits["angular_accel"])
        total += trapezoid_time(distance, limits["max_speed"], limits["linear_accel"])
        heading = bearing
    if goal[2] is not None:
        total += trapezoid_time(math.remainder(goal[2] - heading, math.tau), limits["max_turn"], limits["angular_accel"])
    return total


class _Robot:
    """What the bench reads of one robot: its latest pose and truth, and its goals' ends (from nav/feedback)."""

    def __init__(self, session: Any, keys: Keys) -> None:
        self.keys = keys
        self.session = session
        self.pose: Pose | None = None
        self.truth: Pose | None = None
        self.ends: dict[str, NavFeedback] = {}
        self.changed = threading.Condition()
        self._subscribers = [
            session.declare_subscriber(keys.pose, lambda s: self._set("pose", decode(Pose, s.payload.to_bytes()))),
            session.declare_subscriber(keys.sim_truth, lambda s: self._set("truth", decode(Pose, s.payload.to_bytes()))),
            session.declare_subscriber(keys.nav_feedback, self._feedback),
        ]

    def _set(self, name: str, pose: Pose) -> None:
        setattr(self, name, pose)

    def _feedback(self, sample: Any) -> None:
        feedback = decode(NavFeedback, sample.payload.to_bytes())
        if feedback.state.done:
            with self.changed:
                self.ends[feedback.goal_id] = feedback
                self.changed.notify_all()

    def wait_end(self, goal_id: str, timeout: float) -> NavFeedback:
        """The goal's last feedback; feedback is telemetry (dropped for a congested link), so a goal heard of by no
        feedback for a second is asked for on ``nav/result``."""
        deadline = time.monotonic() + timeout
        while True:
            with self.changed:
                if self.changed.wait_for(lambda: goal_id in self.ends, 1.0):
                    return self.ends[goal_id]
            result = next(
                (decode(NavResult, r.ok.payload.to_bytes()) for r in self.session.get(self.keys.nav_result, payload=encode(
                    NavResultQuery(goal_id=goal_id)), timeout=5.0) if r.ok is not None),
                None,
            )  # fmt: skip
            if result is not None and result.state is not None and result.state.done and result.pose and result.goal:
                return NavFeedback(0.0, goal_id, result.state, result.pose, result.goal, 0.0, 0.0, result.elapsed, reason=result.reason)
            if time.monotonic() > deadline:
                raise TimeoutError(f"goal {goal_id} of {self.keys.prefix} did not end within {timeout:.0f} s")

    def wait_pose(self, timeout: float = 30.0) -> Pose:
        deadline = time.monotonic() + timeout
        while self.pose is None:
            if time.monotonic() > deadline:
                raise TimeoutError(f"no pose from {self.keys.pose} within {timeout:.0f} s")
            time.sleep(0.05)
        return self.pose


def send_goal(session: Any, keys: Keys, goal: NavGoal, patience: float = 15.0) -> tuple[NavGoalReply, float]:
    """The nav service's answer to ``goal`` and when the query that got it was sent (TimeoutError when none answers); a
    refusal because it has not yet heard that the robot's link came up (the gateway's health comes once a second) is
    asked again for ``patience`` s."""
    deadline = time.monotonic() + patience
    while True:
        answer: NavGoalReply | None = None
        sent = time.monotonic()
        for reply in session.get(keys.nav_goal, payload=encode(goal), timeout=5.0):
            if reply.ok is None:
                raise RuntimeError(f"nav/goal answered an error: {reply.err.payload.to_bytes().decode(errors='replace')}")
            answer = decode(NavGoalReply, reply.ok.payload.to_bytes())
        if answer is None:
            raise TimeoutError(f"no navigation service answered on {keys.nav_goal}")
        if answer.accepted or "unreachable" not in answer.reason or time.monotonic() > deadline:
            return answer, sent
        time.sleep(0.2)


def nav_limits(session: Any, keys: Keys) -> dict[str, float]:
    """The navigation's parameters now, by name (numbers only)."""
    for reply in session.get(keys.nav_params, timeout=5.0):
        if reply.ok is not None:
            params = decode(GatewayParams, reply.ok.payload.to_bytes()).params
            return {p.name: float(p.value) for p in params if isinstance(p.value, int | float) and not isinstance(p.value, bool)}
    raise TimeoutError(f"no navigation service answered on {keys.nav_params}")


#: --quick (a smoke run, often on a loaded machine): the navigation tolerates late poses, so that a figure that only
#: proves the path runs is not failed by a host too busy to deliver poses in time (its figures mean nothing then).
QUICK_PARAMS = {"pose_timeout": 3.0, "no_progress_timeout": 60.0}


def set_params(session: Any, keys: Keys, values: dict[str, float]) -> None:
    """Set the navigation's parameters; RuntimeError naming the ones it refused."""
    for reply in session.get(keys.nav_params_set, payload=encode(ParamsSet(values=dict(values))), timeout=5.0):
        if reply.ok is not None:
            refused = [r.reason for r in decode(ParamsSetReply, reply.ok.payload.to_bytes()).results if not r.successful]
            if refused:
                raise RuntimeError(f"the navigation refused {refused}")
            return
    raise TimeoutError(f"no navigation service answered on {keys.nav_params_set}")


def _up(stack: ExitStack, args: list[str]) -> tuple[int, Any]:
    zport = free_port()
    up = service(stack, "up", ["up", "-l", f"tcp/127.0.0.1:{zport}", "--no-multicast-scouting", *args], timeout=15.0)
    return zport, up


def wait_connected(session: Any, keys: Keys, timeout: float = 60.0) -> None:
    """Until the robot's gateway says its control link is up and the e-stop released (the navigation refuses goals before)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for reply in session.get(keys.health, timeout=2.0):
            if reply.ok is not None:
                health = decode(GatewayHealth, reply.ok.payload.to_bytes())
                if health.control.state == "connected" and not health.estop:
                    return
        time.sleep(0.1)
    raise TimeoutError(f"the gateway of {keys.prefix} did not connect to its robot within {timeout:.0f} s")


def _settle(robot: _Robot, seconds: float = 0.3) -> Pose:
    """The robot's pose once it has stood still for ``seconds`` (its last commands have run out)."""
    time.sleep(seconds)
    return robot.wait_pose()


def calibrated_settings(folder: Path) -> Path:
    """``up --settings`` for the robot of UNLIKE: the simulator's truth, the calibrated constants for the others."""
    settings = folder / "calibrated.toml"
    settings.write_text(
        f"wheel_separation = {UNLIKE['wheel_separation']}\n"
        f"impulses_left = {model.IMPULSES_PER_METER_LEFT / UNLIKE['left_wheel_scale']}\n"
        f"impulses_right = {model.IMPULSES_PER_METER_RIGHT / UNLIKE['right_wheel_scale']}\n"
        "[sim]\n" + "".join(f"{key} = {value}\n" for key, value in UNLIKE.items())
    )
    return settings


def nav_goals(plan: Plan, _: Result, calibrated: bool = False) -> Result:
    goals = GOALS if not plan.quick else GOALS[:4]
    name = "nav_goals_calibrated" if calibrated else "nav_goals"
    with ExitStack() as stack:
        args = ["--settings", str(calibrated_settings(Path(stack.enter_context(tempfile.TemporaryDirectory()))))] if calibrated else []
        zport, _up_process = _up(stack, args)
        session = client_session(stack, zport)
        keys = Keys()
        robot = _Robot(session, keys)
        robot.wait_pose()
        wait_connected(session, keys)
        if plan.quick:
            set_params(session, keys, QUICK_PARAMS)
        limits = nav_limits(session, keys)
        rows: list[dict[str, Any]] = []
        for forward, left, turn in goals:
            here = _settle(robot)
            truth0 = robot.truth
            c, s = math.cos(here.yaw), math.sin(here.yaw)
            target = (here.x + c * forward - s * left, here.y + s * forward + c * left, None if turn is None else here.yaw + turn)
            reference = reference_time((here.x, here.y, here.yaw), target, limits)
            reply, t0 = send_goal(session, keys, NavGoal(x=target[0], y=target[1], yaw=target[2], frame="odom"))
            if not reply.accepted or reply.goal_id is None:
                raise RuntimeError(f"goal {target} refused: {reply.reason}")
            end = robot.wait_end(reply.goal_id, timeout=max(60.0, 4 * reference))
            took = time.monotonic() - t0
            if end.state is not GoalState.SUCCEEDED:
                raise RuntimeError(f"goal {target} ended {end.state}: {end.reason}")
            there = _settle(robot)
            yaw_error = 0.0 if target[2] is None else abs(math.remainder(there.yaw - target[2], math.tau))
            truth_error = math.nan
            if truth0 is not None and robot.truth is not None:  # the truth's displacement against the odometry's
                moved_truth = (robot.truth.x - truth0.x, robot.truth.y - truth0.y)
                truth_error = math.hypot(moved_truth[0] - (there.x - here.x), moved_truth[1] - (there.y - here.y))
            rows.append(
                {
                    "goal": [forward, left, turn],
                    "position_error_m": math.hypot(there.x - target[0], there.y - target[1]),
                    "yaw_error_rad": yaw_error,
                    "truth_vs_odometry_m": truth_error,
                    "seconds": took,
                    "reference_s": reference,
                    "time_ratio": took / reference if reference > 0 else math.nan,
                }
            )
    ratios = [r["time_ratio"] for r in rows if math.isfinite(r["time_ratio"]) and r["reference_s"] >= 0.5]
    return {
        name: {
            "goals": rows,
            "limits": limits,
            "position_error_max_m": max(r["position_error_m"] for r in rows),
            "yaw_error_max_rad": max(r["yaw_error_rad"] for r in rows),
            "truth_vs_odometry_max_m": max(
                (r["truth_vs_odometry_m"] for r in rows if math.isfinite(r["truth_vs_odometry_m"])), default=math.nan
            ),
            "time_ratio_max": max(ratios, default=math.nan),
            "time_ratio_median": statistics.median(ratios) if ratios else math.nan,
        }
    }


def _child_pids(parent: int) -> dict[str, int]:
    """The services ``up`` started, by their subcommand (``nav``, ``gateway``, ...)."""
    pids: dict[str, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            if ppid != parent:
                continue
            argv = (stat.parent / "cmdline").read_bytes().split(b"\0")
        except (OSError, ValueError, IndexError):
            continue
        words = [a.decode(errors="replace") for a in argv]
        for i, word in enumerate(words[:-1]):
            if word == "blackmetal" and words[i + 1] and not words[i + 1].startswith("-"):
                pids[words[i + 1]] = int(stat.parent.name)
                break
    return pids


def nav_fleet(plan: Plan, _: Result) -> Result:
    robots = plan.pick(5, 100)
    with ExitStack() as stack:
        zport, up = _up(stack, ["--robots", str(robots)])
        session = client_session(stack, zport)
        prefixes = list(up.ready_info["prefixes"])
        fleet = [_Robot(session, Keys(prefix)) for prefix in prefixes]
        for robot in fleet:
            robot.wait_pose(60.0)
            wait_connected(session, robot.keys)
            if plan.quick:
                set_params(session, robot.keys, QUICK_PARAMS)
        pids = _child_pids(up.proc.pid)
        idle = cpu_window({"nav": pids["nav"]}, plan.pick(2.0, 5.0)) if "nav" in pids else {}
        t0 = time.monotonic()
        ids = {}
        for robot in fleet:
            reply, _sent = send_goal(session, robot.keys, NavGoal(x=FLEET_GOAL[0], y=FLEET_GOAL[1], yaw=FLEET_GOAL[2], frame="odom"))
            if not reply.accepted or reply.goal_id is None:
                raise RuntimeError(f"{robot.keys.prefix}: goal refused: {reply.reason}")
            ids[robot.keys.prefix] = reply.goal_id
        accepted_s = time.monotonic() - t0
        healths: dict[str, list[float]] = {}
        watch = session.declare_subscriber(
            "fleet/*/gateway/health",
            lambda s: healths.setdefault(str(s.key_expr), []).append(decode(GatewayHealth, s.payload.to_bytes()).poll_hz),
        )
        driving = cpu_window(pids, plan.pick(2.0, 4.0))
        ends = [robot.wait_end(ids[robot.keys.prefix], timeout=120.0) for robot in fleet]
        all_done_s = time.monotonic() - t0
        watch.undeclare()
    # each health's poll_hz is its gateway's rate over the second before it: a robot's rate while driving is their median
    polls = [statistics.median(values) for values in healths.values() if values]
    lowest = min((min(values) for values in healths.values() if values), default=0.0)
    succeeded = sum(1 for end in ends if end.state is GoalState.SUCCEEDED)
    return {
        "nav_fleet": {
            "robots": robots,
            "succeeded": succeeded,
            "position_error_max_m": max((math.hypot(e.pose.x - e.goal.x, e.pose.y - e.goal.y) for e in ends), default=math.nan),
            "not_succeeded": [f"{end.goal_id}: {end.state} {end.reason}" for end in ends if end.state is not GoalState.SUCCEEDED][:5],
            "goals_sent_s": accepted_s,
            "all_done_s": all_done_s,
            "poll_hz_min_driving": min(polls, default=0.0),
            "poll_hz_lowest_report": lowest,
            "robots_reporting": len(polls),
            "nav_cores_idle": idle.get("nav", math.nan),
            "nav_cores_driving": driving.get("nav", math.nan),
            "cores_driving": driving,
        }
    }


def _goals_rows(f: Result, name: str = "nav_goals") -> list[Row]:
    g = f[name]
    n = len(g["goals"])
    robot = ", a robot unlike its drawing, calibrated" if name != "nav_goals" else ""
    return [
        (f"nav: {n} goals{robot}, worst position error (odometry)", f"{g['position_error_max_m'] * 100:.2f} cm", f"bar {POSITION_BAR_M * 100:g} cm",
         met(g["position_error_max_m"] <= POSITION_BAR_M).removeprefix(": ")),
        ("nav: worst yaw error", f"{math.degrees(g['yaw_error_max_rad']):.2f} deg", f"bar {math.degrees(YAW_BAR_RAD):g} deg",
         met(g["yaw_error_max_rad"] <= YAW_BAR_RAD).removeprefix(": ")),
        ("nav: time against a trapezoidal profile", f"worst {g['time_ratio_max']:.2f}x, median {g['time_ratio_median']:.2f}x",
         "same limits, same run", f"<= {TIME_BAR:g}x{met(g['time_ratio_max'] <= TIME_BAR)}"),
        ("nav: truth against odometry (displacement)", f"{g['truth_vs_odometry_max_m'] * 100:.2f} cm", "the simulator's truth", ""),
    ]  # fmt: skip


def _fleet_rows(f: Result) -> list[Row]:
    g = f["nav_fleet"]
    return [
        (f"nav: {g['robots']} robots navigating at once", f"{g['succeeded']} of {g['robots']} succeeded in {g['all_done_s']:.1f} s, worst {g['position_error_max_m'] * 100:.2f} cm off",
         f"goals sent in {g['goals_sent_s'] * 1e3:.0f} ms", ""),
        ("nav: poll rate while they drive", f"{g['poll_hz_min_driving']:.1f} Hz (slowest robot; lowest one-second report {g['poll_hz_lowest_report']:.1f})", "50 Hz polled", f">= 49 Hz{met(g['poll_hz_min_driving'] >= 49)}"),
        ("nav: the navigation process's CPU", f"{g['nav_cores_driving']:.3f} cores driving, {g['nav_cores_idle']:.3f} idle",
         f"per {g['robots']} robots", f"<= {0.15 * g['robots'] / 100:.3f}{met(g['nav_cores_driving'] <= 0.15 * g['robots'] / 100)}"),
    ]  # fmt: skip


NAV_GOALS = Figure("nav_goals", "navigation, 20 goals", "sending one robot 20 goals ...", ("nav_goals",), nav_goals, _goals_rows)
NAV_GOALS_CALIBRATED = Figure(
    "nav_goals_calibrated",
    "navigation, 20 goals, a calibrated robot",
    "sending a robot unlike its drawing, calibrated, 20 goals ...",
    ("nav_goals_calibrated",),
    partial(nav_goals, calibrated=True),
    partial(_goals_rows, name="nav_goals_calibrated"),
)
NAV_FLEET = Figure(
    "nav_fleet", "navigation, a fleet", "sending every robot of a fleet a goal at once ...", ("nav_fleet",), nav_fleet, _fleet_rows
)
