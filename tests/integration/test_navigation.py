"""Navigation end to end, real processes on loopback: the simulator, a gateway, an odometry and ``blackmetal nav``;
goals sent by ``blackmetal goto`` as a person sends them, the robot's arrival judged by the simulator's truth.

- ``goto 0.5 0.3 90`` reaches the goal (the truth within 3 cm and 2 degrees of it);
- a goal while the e-stop is engaged is rejected with its sentence, and nothing moves;
- an e-stop during a goal aborts it with its reason, and after the release the robot stays still;
- teleop taking over for longer than the override timeout aborts the goal, and nothing resumes it;
- Ctrl-C of goto (SIGINT) cancels the goal: exit 130, no traceback, and the robot stops;
- the odometry killed during a goal aborts it, and the robot stops;
- a flood of goals, a third of them not goals, each answered; relative moves (``--move``, ``--turn``); one sentence
  when no navigation answers on a prefix.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass

import pytest
import zenoh
from helpers import Child, SimProcess, client_config, free_port, wait_for, zenoh_connect_args, zenoh_listen_args

from blackmetal.schemas import GatewayHealth, Pose, decode

pytestmark = pytest.mark.integration

#: The truth must come within this of the goal (m): 2 cm of the odometry's tolerance and the simulator's errors.
TRUTH_TOLERANCE_M = 0.03
TRUTH_TOLERANCE_RAD = math.radians(2.0)


@dataclass
class Robot:
    zport: int
    endpoint: str
    processes: list[Child]

    def session(self) -> zenoh.Session:
        return zenoh.open(client_config(self.zport))


@pytest.fixture(scope="module")
def robot() -> Iterator[Robot]:
    """The simulator (the hub), a gateway, an odometry and a navigation, started in that order, all ready."""
    zport = free_port()
    processes: list[Child] = []
    try:
        sim = SimProcess(*zenoh_listen_args(zport))
        processes.append(sim)
        nav = Child(["-m", "blackmetal", "nav", *zenoh_connect_args(zport)])  # before the gateway: any start order
        processes.append(nav)
        nav.ready()
        gateway = Child(
            ["-m", "blackmetal", "gateway", "--control-port", str(sim.control_port), "--log-port", str(sim.log_port),
             *zenoh_connect_args(zport)]
        )  # fmt: skip
        odometry = Child(["-m", "blackmetal", "odometry", *zenoh_connect_args(zport)])
        processes += [gateway, odometry]
        gateway.ready()
        odometry.ready()
        found = Robot(zport, f"tcp/127.0.0.1:{zport}", processes)
        with found.session() as session:  # what nav hears too: a published health that says the robot is connected
            published: list[GatewayHealth] = []
            session.declare_subscriber("robot/gateway/health", lambda s: published.append(decode(GatewayHealth, s.payload.to_bytes())))
            wait_for(lambda: published and published[-1].control.state == "connected", what="the gateway connected to the robot")
            wait_for(lambda: get(session, "robot/pose", Pose), what="a pose")
        yield found
    finally:
        for process in reversed(processes):
            process.stop()


def get(session: zenoh.Session, key: str, message: type, payload: bytes | None = None):  # type: ignore[no-untyped-def]
    for reply in session.get(key, payload=payload, timeout=5):
        if reply.ok is not None:
            return decode(message, reply.ok.payload.to_bytes())
    return None


def truth(session: zenoh.Session) -> Pose:
    pose = wait_for(lambda: get(session, "robot/sim/truth", Pose), what="the simulator's truth")
    assert isinstance(pose, Pose)
    return pose


def goto(robot: Robot, *argv: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "blackmetal", "goto", *argv, "-e", robot.endpoint, "--no-multicast-scouting", "--wait", "20"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish(process: subprocess.Popen[str], timeout: float = 120) -> tuple[int, str, str]:
    try:
        out, err = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        out, err = process.communicate()
        raise AssertionError(f"goto still running after {timeout:g} s:\n{out}\n{err}") from None
    return process.returncode, out, err


def estop(robot: Robot, state: str) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "blackmetal", "estop", state, "-e", robot.endpoint, "--no-multicast-scouting", "--timeout", "10"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stdout + done.stderr


def relative(start: Pose, now: Pose) -> tuple[float, float, float]:
    """``now`` in the frame of ``start`` (the truth's own origin is the simulator's, not the odometry's)."""
    dx, dy = now.x - start.x, now.y - start.y
    c, s = math.cos(-start.yaw), math.sin(-start.yaw)
    return c * dx - s * dy, s * dx + c * dy, math.remainder(now.yaw - start.yaw, math.tau)


def still(session: zenoh.Session) -> Pose:
    """The truth once the robot stands still."""
    pose = wait_for(lambda: (p := get(session, "robot/sim/truth", Pose)) is not None and p.v == 0.0 and p.w == 0.0 and p,
                    what="the robot standing still")  # fmt: skip
    assert isinstance(pose, Pose)
    return pose


def stays_still(session: zenoh.Session, seconds: float = 1.5) -> None:
    before = still(session)
    time.sleep(seconds)  # nothing to wait for: the point is that nothing happens
    after = truth(session)
    assert math.hypot(after.x - before.x, after.y - before.y) < 0.001 and abs(after.yaw - before.yaw) < 0.002, (before, after)


def moving(session: zenoh.Session) -> None:
    wait_for(lambda: (p := get(session, "robot/sim/truth", Pose)) is not None and (abs(p.v) > 0.05 or abs(p.w) > 0.1),
             what="the robot moving for the goal")  # fmt: skip


def test_goto_reaches_the_goal_by_the_simulators_truth(robot: Robot) -> None:
    with robot.session() as session:
        start = still(session)
        assert get(session, "robot/odometry/reset", Pose) is not None  # odom's origin where the robot stands: map = odom here
        code, out, err = finish(goto(robot, "0.5", "0.3", "90"))
        assert code == 0, out + err
        assert "blackmetal goto: reached (0.500, 0.300, 90.0°) in map" in out, out
        x, y, yaw = relative(start, still(session))
    print(f"goto 0.5 0.3 90: truth off by {1000 * math.hypot(x - 0.5, y - 0.3):.1f} mm, {math.degrees(yaw - math.pi / 2):+.2f} deg")
    assert math.hypot(x - 0.5, y - 0.3) < TRUTH_TOLERANCE_M, (x, y)
    assert abs(math.remainder(yaw - math.pi / 2, math.tau)) < TRUTH_TOLERANCE_RAD, math.degrees(yaw)


def test_relative_moves_drive_and_turn_as_asked(robot: Robot) -> None:
    with robot.session() as session:
        start = still(session)
        code, out, err = finish(goto(robot, "--move", "0.3"))
        assert code == 0, out + err
        x, y, yaw = relative(start, still(session))
        assert math.hypot(x - 0.3, y) < TRUTH_TOLERANCE_M and abs(yaw) < TRUTH_TOLERANCE_RAD, (x, y, yaw)
        start = still(session)
        code, out, err = finish(goto(robot, "--turn", "-90"))
        assert code == 0, out + err
        x, y, yaw = relative(start, still(session))
        assert math.hypot(x, y) < TRUTH_TOLERANCE_M and abs(math.remainder(yaw + math.pi / 2, math.tau)) < TRUTH_TOLERANCE_RAD


def test_a_goal_while_the_estop_is_engaged_is_rejected_with_its_sentence(robot: Robot) -> None:
    estop(robot, "on")
    try:
        with robot.session() as session:
            before = still(session)
            code, out, err = finish(goto(robot, "1", "0"))
            assert code == 1, out + err
            assert out.startswith("blackmetal goto: goal rejected: ") and "e-stop" in out.lower(), out
            after = truth(session)
            assert math.hypot(after.x - before.x, after.y - before.y) < 0.001
    finally:
        estop(robot, "off")


def test_an_estop_during_a_goal_aborts_it_and_nothing_moves_after_the_release(robot: Robot) -> None:
    with robot.session() as session:
        running = goto(robot, "2.5", "0")
        try:
            moving(session)
            estop(robot, "on")
            code, out, err = finish(running)
        finally:
            if running.poll() is None:
                running.kill()
        try:
            assert code == 1, out + err
            assert "blackmetal goto: goal aborted after" in out and "e-stop" in out.lower(), out
            health = get(session, "robot/gateway/health", GatewayHealth)
            assert health is not None and health.estop
        finally:
            estop(robot, "off")
        stays_still(session)  # no goal resumes after the release


def test_teleop_taking_over_for_longer_than_the_override_timeout_aborts_the_goal(robot: Robot) -> None:
    """teleop (priority 100) wins over nav (10) at once; after override_timeout (2 s) the goal ends aborted, and when
    teleop lets go nothing resumes it."""
    with robot.session() as session:
        running = goto(robot, "-1.5", "-1")
        try:
            moving(session)
            end = time.monotonic() + 3.0
            while time.monotonic() < end and running.poll() is None:
                session.put("robot/cmd_vel/teleop", b'{"linear": {"x": 0.0}}')  # an operator holds the robot still
                time.sleep(0.1)
            code, out, err = finish(running, timeout=30)
        finally:
            if running.poll() is None:
                running.kill()
        assert code == 1, out + err
        assert "blackmetal goto: goal aborted after" in out and "overridden" in out and "teleop" in out, out
        stays_still(session)


def test_ctrl_c_of_goto_cancels_the_goal_and_the_robot_stops(robot: Robot) -> None:
    with robot.session() as session:
        running = goto(robot, "-2", "0.5")
        try:
            moving(session)
            running.send_signal(signal.SIGINT)
            code, out, err = finish(running, timeout=30)
        finally:
            if running.poll() is None:
                running.kill()
        assert code == 130, out + err
        assert "Traceback" not in err, err
        assert "blackmetal goto: interrupted: goal canceled, the robot stops" in out, out
        stays_still(session)


def test_a_flood_of_goals_is_answered_goal_by_goal_and_nothing_crashes(robot: Robot) -> None:
    """300 goals at once, a third of them not a goal: each gets its answer (accepted, each preempting the last, or
    refused with the reason); the navigation lives on, and a cancel stops the robot."""
    import json
    import threading

    with robot.session() as session:
        still(session)
        answers: list[dict[str, object]] = []
        lock = threading.Lock()

        def send(k: int) -> None:
            payload = json.dumps({"x": 0.3 + 0.0001 * k, "y": 0.0, "frame": "odom"}) if k % 3 else '{"x": "NaN", "y": 0}'
            replies = [r for r in session.get("robot/nav/goal", payload=payload, timeout=10) if r.ok is not None]
            with lock:
                answers.extend(json.loads(r.ok.payload.to_bytes()) for r in replies)

        threads = [threading.Thread(target=send, args=(k,)) for k in range(300)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(30)
        assert len(answers) == 300
        assert sum(bool(a["accepted"]) for a in answers) == 200
        assert {str(a["reason"]).split(":")[0] for a in answers if not a["accepted"]} == {"invalid NavGoal"}
        cancel = [r for r in session.get("robot/nav/cancel", timeout=5) if r.ok is not None]
        assert cancel, "the navigation no longer answers"
        stays_still(session)
    assert all(process.poll() is None for process in robot.processes)


def test_a_prefix_without_navigation_is_one_sentence(robot: Robot) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "blackmetal", "goto", "1", "1", "--prefix", "nobody", "-e", robot.endpoint, "--no-multicast-scouting",
         "--wait", "1"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 1
    assert (
        done.stderr == "blackmetal goto: no navigation service on nobody/nav/goal: is `blackmetal nav` running (blackmetal up starts it)?\n"
    )


def test_up_starts_the_navigation_and_starts_it_again_when_it_dies() -> None:
    """``blackmetal up``: nav is one of its processes; killed, it is started again and takes goals."""
    zport = free_port()
    endpoint = f"tcp/127.0.0.1:{zport}"
    up = Child(["-m", "blackmetal", "up", "-l", endpoint, "--no-multicast-scouting"])
    try:
        children = up.ready(timeout=90)["children"]
        assert "nav" in children
        up.wait_line(rf"blackmetal goto 0\.5 0\.3 90 -e {endpoint}")
        os.kill(children["nav"], signal.SIGKILL)
        up.wait_line(r"nav gone; its goals ended; the gateway's command timeout stops a robot it drove")
        up.wait_line(r"nav started again \(pid \d+\)")
        done = subprocess.run(
            [sys.executable, "-m", "blackmetal", "goto", "--move", "0.1", "-e", endpoint, "--no-multicast-scouting", "--wait", "30"],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert done.returncode == 0, done.stdout + done.stderr
        assert up.poll() is None
    finally:
        up.stop()


def test_a_fleets_navigation_drives_the_robot_it_is_asked_to_alone() -> None:
    """``up --robots 2``: one ``nav --fleet`` for both; a move for r2 moves r2, and r1 stays where it is."""
    zport = free_port()
    endpoint = f"tcp/127.0.0.1:{zport}"
    up = Child(["-m", "blackmetal", "up", "--robots", "2", "-l", endpoint, "--no-multicast-scouting"])
    try:
        assert "nav" in up.ready(timeout=90)["children"]
        with zenoh.open(client_config(zport)) as session:
            starts = {p: wait_for(lambda p=p: get(session, f"fleet/{p}/sim/truth", Pose), what=f"{p}'s truth") for p in ("r1", "r2")}
            done = subprocess.run(
                [sys.executable, "-m", "blackmetal", "goto", "--move", "0.25", "--prefix", "fleet/r2", "-e", endpoint,
                 "--no-multicast-scouting", "--wait", "30"],
                capture_output=True, text=True, timeout=120,
            )  # fmt: skip
            assert done.returncode == 0, done.stdout + done.stderr
            assert "accepted on fleet/r2" in done.stdout
            ends = {p: get(session, f"fleet/{p}/sim/truth", Pose) for p in ("r1", "r2")}
        x, y, _ = relative(starts["r2"], ends["r2"])
        assert math.hypot(x - 0.25, y) < TRUTH_TOLERANCE_M, (x, y)
        assert math.hypot(ends["r1"].x - starts["r1"].x, ends["r1"].y - starts["r1"].y) < 0.001
    finally:
        up.stop()


def test_the_odometry_killed_during_a_goal_aborts_it_and_the_robot_stops() -> None:
    """Pose lost: the goal ends aborted with its reason, and the robot stands still within the command timeout."""
    zport = free_port()
    processes: list[Child] = []
    try:
        sim = SimProcess(*zenoh_listen_args(zport))
        processes.append(sim)
        for args in (["gateway", "--control-port", str(sim.control_port), "--log-port", str(sim.log_port)], ["odometry"], ["nav"]):
            processes.append(Child(["-m", "blackmetal", *args, *zenoh_connect_args(zport)]))
            processes[-1].ready()
        odometry = processes[2]
        robot = Robot(zport, f"tcp/127.0.0.1:{zport}", processes)
        with robot.session() as session:
            wait_for(lambda: (h := get(session, "robot/gateway/health", GatewayHealth)) is not None and h.control.state == "connected",
                     what="the gateway connected")  # fmt: skip
            running = goto(robot, "3", "0")
            try:
                moving(session)
                odometry.proc.kill()
                code, out, err = finish(running, timeout=30)
            finally:
                if running.poll() is None:
                    running.kill()
            assert code == 1, out + err
            assert "blackmetal goto: goal aborted after" in out and ("pose" in out or "odometry" in out), out
            stays_still(session)
    finally:
        for process in reversed(processes):
            process.stop()
