"""``blackmetal square``: drive a square on odometry and report how well it closes (UMBmark).

The robot drives ``--size`` metres, stops, turns 90 degrees, stops, four
times, steering by its own odometry (as a robot does). It then reports the
closure error: where the odometry believes it ended relative to where it
started, and, with the simulator, where it really ended. Their difference is
the odometry's error. ``--both`` drives counter-clockwise then clockwise,
as UMBmark does; ``--plot out.png`` draws odometry against truth (needs the
``plot`` extra: matplotlib); ``--record run.mcap`` records the run
(impulses, poses, truth, cmd_vel, and each square's span as MCAP metadata)
for ``blackmetal replay`` and ``blackmetal calibrate``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from blackmetal.odometry_service.calibration import centre_of_gravity
from blackmetal.recording.writer import McapRecording, SessionRecorder
from blackmetal.runtime.signals import stop_on_signals
from blackmetal.schemas import Pose, Twist, Vector3, encode, require_extra

from .client import Latest, ToolError, add_client_arguments, add_drive_arguments, connect, require_gateway, require_pose, tool

RATE_HZ = 20.0
#: Commanding motion for this long without the pose changing means the commands have no effect (s).
NO_EFFECT_S = 5.0
#: The robot stands still this long before each leg and turn (s): ten poses at 50 Hz.
SETTLE_S = 0.2
#: Near the end of a leg or a turn, speed is the distance or angle left over the gateway's command
#: timeout (from its health), with a floor that still moves the wheels: if this tool stalls, the last
#: command runs until that timeout and must not carry the robot past the corner. A gateway without a
#: timeout gets the gain of the default 0.5 s; above MAX_APPROACH_GAIN the 20 Hz loop, fed poses a
#: poll or two old, would overshoot.
DEFAULT_APPROACH_GAIN = 2.0
MAX_APPROACH_GAIN = 8.0
MIN_SPEED = 0.03
MIN_TURN_RATE = 0.08


@dataclass
class Closure:
    """End pose relative to the start pose, in the start's frame."""

    dx: float
    dy: float
    dyaw: float

    @property
    def distance(self) -> float:
        return math.hypot(self.dx, self.dy)

    def as_dict(self) -> dict[str, float]:
        return {"dx_m": self.dx, "dy_m": self.dy, "dyaw_rad": self.dyaw, "distance_m": self.distance}


def closure(start: Pose, end: Pose) -> Closure:
    ((dx, dy),) = _in_frame_of(start, [(end.x, end.y)])
    return Closure(dx, dy, math.remainder(end.yaw - start.yaw, math.tau))


@dataclass
class Run:
    direction: str
    odometry: Closure
    truth: Closure | None
    odometry_path: list[tuple[float, float]] = field(default_factory=list)
    truth_path: list[tuple[float, float]] = field(default_factory=list)


def approach_gain(cmd_timeout: float) -> float:
    """Speed per distance left (1/s) such that a last command run for ``cmd_timeout`` stops at the corner."""
    if not cmd_timeout > 0:
        return DEFAULT_APPROACH_GAIN
    return min(MAX_APPROACH_GAIN, 1.0 / cmd_timeout)


class Cancelled(ToolError):
    """Ctrl-C while driving: the robot was stopped."""


@dataclass
class Driver:
    """Closed-loop legs on the odometry pose, publishing cmd_vel at 20 Hz."""

    publisher: zenoh.Publisher
    pose: Latest
    truth: Latest | None
    speed: float
    turn_rate: float
    stop: threading.Event
    approach_gain: float  # approach_gain() of the gateway's command timeout
    odometry_path: list[tuple[float, float]] = field(default_factory=list)
    truth_path: list[tuple[float, float]] = field(default_factory=list)
    _moved_at: float = field(default_factory=time.monotonic)
    _last_pose: tuple[float, float, float] | None = None
    _rest: Pose | None = None  # where settle() found the robot at rest; None once motion is commanded

    def _send(self, v: float, w: float) -> None:
        if v or w:
            self._rest = None
        self.publisher.put(encode(Twist(linear=Vector3(x=v), angular=Vector3(z=w))))

    def _check_effect(self, pose: Pose) -> None:
        """While motion is commanded: a pose unchanged for NO_EFFECT_S means the commands do nothing."""
        now = time.monotonic()
        here = (pose.x, pose.y, pose.yaw)
        if here != self._last_pose:
            self._last_pose, self._moved_at = here, now
        elif now - self._moved_at > NO_EFFECT_S:
            self._send(0.0, 0.0)
            raise ToolError(
                f"the robot has not moved for {NO_EFFECT_S:g} s of cmd_vel: the commands have no effect. Is this user "
                "allowed to put on cmd_vel (the router's access control), is the e-stop engaged, is the gateway connected?"
            )

    def _step(self) -> Pose:
        if self.stop.wait(1.0 / RATE_HZ):
            self._send(0.0, 0.0)
            raise Cancelled
        pose: Pose = self.pose.value
        self.odometry_path.append((pose.x, pose.y))
        if self.truth is not None and self.truth.value is not None:
            self.truth_path.append((self.truth.value.x, self.truth.value.y))
        if self.pose.age() > 1.0:
            self._send(0.0, 0.0)
            raise ToolError("the odometry stopped publishing poses for more than 1 s; stopped the robot")
        return pose

    def settle(self) -> Pose:
        """Zero velocity until the odometry has stood still for SETTLE_S; at once if it has since the last motion."""
        if self._rest is not None:
            return self._rest
        still_since = None
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            self._send(0.0, 0.0)
            pose = self._step()
            if abs(pose.v) < 1e-6 and abs(pose.w) < 1e-6:
                still_since = still_since or time.monotonic()
                if time.monotonic() - still_since >= SETTLE_S:
                    self._rest = pose
                    return pose
            else:
                still_since = None
        raise ToolError("the robot did not come to rest within 10 s")

    def straight(self, distance: float) -> None:
        start = self.settle()
        heading = start.yaw
        while True:
            pose = self._step()
            along = (pose.x - start.x) * math.cos(heading) + (pose.y - start.y) * math.sin(heading)
            remaining = distance - along
            if remaining <= 0.001:
                break
            v = max(MIN_SPEED, min(self.speed, self.approach_gain * remaining))
            w = max(-0.5, min(0.5, 2.0 * math.remainder(heading - pose.yaw, math.tau)))
            self._send(v, w)
            self._check_effect(pose)
        self.settle()

    def turn(self, angle: float) -> None:
        start = self.settle()
        target = start.yaw + angle
        while True:
            pose = self._step()
            error = math.remainder(target - pose.yaw, math.tau)
            if abs(error) <= 0.002 or error * angle < 0:
                break
            w = math.copysign(max(MIN_TURN_RATE, min(self.turn_rate, self.approach_gain * abs(error))), error)
            self._send(0.0, w)
            self._check_effect(pose)
        self.settle()


def drive_square(driver: Driver, size: float, clockwise: bool) -> Run:
    truth = driver.truth
    start = driver.settle()
    truth_start: Pose | None = truth.value if truth is not None else None
    driver.odometry_path, driver.truth_path = [], []
    direction = "clockwise" if clockwise else "counter-clockwise"
    for side in range(1, 5):
        print(f"  {direction}: side {side} of 4, {size:g} m, then a {'right' if clockwise else 'left'} turn", flush=True)
        driver.straight(size)
        driver.turn(-math.pi / 2 if clockwise else math.pi / 2)
    end = driver.settle()
    truth_end: Pose | None = truth.value if truth is not None else None
    return Run(
        direction,
        closure(start, end),
        closure(truth_start, truth_end) if truth_start is not None and truth_end is not None else None,
        _in_frame_of(start, driver.odometry_path),
        _in_frame_of(truth_start, driver.truth_path) if truth_start is not None else [],
    )


def _in_frame_of(origin: Pose, path: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Points relative to a start pose, so odometry and truth paths overlay from the same origin."""
    c, s = math.cos(-origin.yaw), math.sin(-origin.yaw)
    return [(c * (x - origin.x) - s * (y - origin.y), s * (x - origin.x) + c * (y - origin.y)) for x, y in path]


def report(run: Run) -> str:
    o = run.odometry
    text = f"{run.direction}: odometry closure {1000 * o.distance:.1f} mm (dx {1000 * o.dx:+.1f}, dy {1000 * o.dy:+.1f}), yaw {1000 * o.dyaw:+.1f} mrad"
    if run.truth is not None:
        t = run.truth
        text += (
            f"\n{' ' * len(run.direction)}  truth    closure {1000 * t.distance:.1f} mm (dx {1000 * t.dx:+.1f}, dy {1000 * t.dy:+.1f}), yaw {1000 * t.dyaw:+.1f} mrad"
            f"\n{' ' * len(run.direction)}  odometry error {1000 * math.hypot(o.dx - t.dx, o.dy - t.dy):.1f} mm, {1000 * abs(math.remainder(o.dyaw - t.dyaw, math.tau)):.1f} mrad"
        )
    return text


def umbmark_figure(runs: list[Run]) -> str | None:
    """UMBmark's E_max,syst (None without the simulator's truth) and the calibrate command of the true ends. A return
    error is the true end minus the odometry's (start frame), so the driver's own stopping error is not counted."""
    errors: dict[str, list[tuple[float, float]]] = {"clockwise": [], "counter-clockwise": []}
    ends: dict[str, list[tuple[float, float]]] = {"clockwise": [], "counter-clockwise": []}
    for run in runs:
        if run.truth is None:
            return None
        errors[run.direction].append((run.truth.dx - run.odometry.dx, run.truth.dy - run.odometry.dy))
        ends[run.direction].append((run.truth.dx, run.truth.dy))
    if not errors["clockwise"] or not errors["counter-clockwise"]:
        return None
    cw, ccw = centre_of_gravity(errors["clockwise"]), centre_of_gravity(errors["counter-clockwise"])
    e_max = max(math.hypot(*cw), math.hypot(*ccw))
    cw_end = " ".join(f"--cw-end={x:.4f},{y:.4f}" for x, y in ends["clockwise"])
    ccw_end = " ".join(f"--ccw-end={x:.4f},{y:.4f}" for x, y in ends["counter-clockwise"])
    return (
        f"UMBmark E_max,syst {1000 * e_max:.1f} mm (centres of gravity of the true ends minus the odometry's: clockwise ({1000 * cw[0]:+.1f}, {1000 * cw[1]:+.1f}) mm, "
        f"counter-clockwise ({1000 * ccw[0]:+.1f}, {1000 * ccw[1]:+.1f}) mm, {len(errors['clockwise'])} run(s) each way)\n"
        f"  UMBmark correction from the true ends: blackmetal calibrate RECORDING {cw_end} {ccw_end}"
    )


def _matplotlib() -> Any:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise ToolError("--plot needs matplotlib: pip install 'blackmetal[plot]'") from None
    return plt


def plot(runs: list[Run], path: str) -> None:
    plt = _matplotlib()
    fig, ax = plt.subplots(figsize=(6, 6))
    for run in runs:
        if run.odometry_path:
            xs, ys = zip(*run.odometry_path, strict=False)
            ax.plot(xs, ys, label=f"odometry ({run.direction})")
        if run.truth_path:
            xs, ys = zip(*run.truth_path, strict=False)
            ax.plot(xs, ys, "--", label=f"truth ({run.direction})")
    ax.set(aspect="equal", xlabel="x (m)", ylabel="y (m)", title="blackmetal square")
    ax.grid(True)
    ax.legend()
    fig.savefig(path, dpi=120)
    plt.close(fig)


@tool("square")
def run(args: argparse.Namespace) -> int:
    if args.plot:
        _matplotlib()  # before driving the whole route, not after
    if args.record:
        require_extra("blackmetal square --record", "record", "mcap")
    if args.repeat < 1:
        raise ToolError(f"--repeat must be at least 1, got {args.repeat}")
    keys, settings, session = connect(args)
    stop = stop_on_signals()
    recorder: SessionRecorder | None = None
    with session:
        try:
            if args.record:
                recording = McapRecording(Path(args.record), keys)
                recorder = SessionRecorder(session, [keys.impulses, keys.pose, keys.sim_truth, keys.cmd_vel], recording)
            health = require_gateway(session, keys, settings, args.wait)
            if health.estop:
                raise ToolError("the emergency stop is engaged; release it first with `blackmetal estop off` (same -e and --prefix)")
            pose = Latest(session, keys.pose, Pose, require_pose(session, keys, settings, args.wait))
            truth = Latest(session, keys.sim_truth, Pose)
            has_truth = truth.wait(2.0) is not None  # the simulator's
            pose.wait(2.0)
            publisher = session.declare_publisher(keys.cmd_vel, express=True)
            driver = Driver(
                publisher, pose, truth if has_truth else None, args.speed, args.turn_rate, stop, approach_gain(health.cmd_timeout)
            )
            print(f"blackmetal square: {args.size} m at {args.speed} m/s on {args.prefix} via {settings.where()}", flush=True)
            runs = []
            for clockwise in ([False, True] if args.both else [args.clockwise]) * args.repeat:
                started = time.time_ns()
                result = drive_square(driver, args.size, clockwise)
                runs.append(result)
                if recorder is not None:
                    span = dict(direction=result.direction, size_m=repr(args.size), start_ns=str(started), end_ns=str(time.time_ns()))
                    recorder.note("blackmetal.square", span)
                print(report(result), flush=True)
        except Cancelled:
            print("blackmetal square: cancelled; robot stopped", file=sys.stderr)
            return 130
        finally:
            if recorder is not None:
                recorder.stop()
                print(f"recorded {', '.join(str(f) for f in recorder.recording.files)}", flush=True)
    if args.both and (figure := umbmark_figure(runs)):
        print(figure, flush=True)
    if args.json:
        out = [{"direction": r.direction, "odometry": r.odometry.as_dict(), "truth": r.truth.as_dict() if r.truth else None} for r in runs]
        print(json.dumps(out))
    if args.plot:
        plot(runs, args.plot)
        print(f"wrote {args.plot}")
    return 0


def build_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--size", type=float, default=1.0, help="side length, m (default 1)")
    add_drive_arguments(parser, turn_rate=0.6)
    parser.add_argument("--clockwise", action="store_true", help="drive clockwise (default counter-clockwise)")
    parser.add_argument("--both", action="store_true", help="counter-clockwise, then clockwise (UMBmark)")
    parser.add_argument(
        "--repeat", type=int, default=1, metavar="N", help="drive the square(s) N times (UMBmark: centres of gravity of the end points)"
    )
    parser.add_argument("--plot", metavar="PNG", help="draw odometry vs truth (needs matplotlib)")
    parser.add_argument("--json", action="store_true", help="also print the closures as JSON")
    parser.add_argument("--record", metavar="FILE.mcap", help="record the run (impulses, poses, truth, cmd_vel) for replay and calibration")
    add_client_arguments(parser)
