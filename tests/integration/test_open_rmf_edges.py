"""Open-RMF's free_fleet at the edges (issue #39): docs/open-rmf.md's recipes as written, bad goals and a flood of
goals on free_fleet's keys, and a robot that differs from its nominal constants, calibrated or not.

The client and the site are tests/integration/test_open_rmf.py's (free_fleet's Nav2 robot adapter, call for
call: tests/free_fleet_client.py).
"""

from __future__ import annotations

import json
import math
import re
import struct
import time
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import free_fleet_client as ff
import pytest
import zenoh
from free_fleet_client import (
    UUID,
    CancelGoalRequest,
    CancelGoalResponse,
    FreeFleetRobot,
    GetResultRequest,
    GetResultResponse,
    GoalInfo,
    GoalStatus,
    Header,
    Point,
    PoseStamped,
    Quaternion,
    SendGoalRequest,
    SendGoalResponse,
    Time,
)
from helpers import Child, client_config, free_port, free_ports, wait_for, zenoh_connect_args

from blackmetal import robot_model as model
from integration.test_open_rmf import SERVICE_CALL_TIMEOUT_S, UPDATE_PERIOD_S, Truth, angle, drive_to_done, on_map, robot_ready, start_site

pytestmark = pytest.mark.integration


@pytest.fixture
def site(children: list[Child]) -> Iterator[zenoh.Session]:
    port = start_site(children)
    with zenoh.open(client_config(port)) as session:
        robot_ready(session)
        yield session


# ------------------------------------------------------------------ docs/open-rmf.md's recipes, as written there
def docs_toml_blocks() -> list[dict[str, Any]]:
    """The TOML blocks of docs/open-rmf.md, parsed."""
    text = (Path(__file__).resolve().parents[2] / "docs" / "open-rmf.md").read_text()
    return [tomllib.loads(block) for block in re.findall(r"```toml\n(.*?)```", text, flags=re.S)]


def test_the_docs_settings_file_with_up_puts_the_robot_on_the_map_for_free_fleet(children: list[Child], tmp_path: Path) -> None:
    site_settings = docs_toml_blocks()[0]
    assert site_settings["ros2"]["rmf"] is True
    settings = tmp_path / "site.toml"
    settings.write_text(f"[nav]\nmap_pose = {site_settings['nav']['map_pose']}\n\n[ros2]\nrmf = true\n")
    port = free_port()
    up = Child(["-m", "blackmetal", "up", "--ros2", "--settings", str(settings), "-l", f"tcp/127.0.0.1:{port}"])
    children.append(up)
    up.ready(timeout=90)
    with zenoh.open(client_config(port)) as session:
        robot_ready(session)
        robot = FreeFleetRobot(session, "robot", service_call_timeout_sec=SERVICE_CALL_TIMEOUT_S)
        try:
            pose, _ = robot.initialize()
            x, y, yaw = site_settings["nav"]["map_pose"]
            assert (pose[0], pose[1]) == pytest.approx((x, y), abs=0.01) and angle(pose[2], yaw) < math.radians(1)
            goal = (x + 0.3 * math.cos(yaw), y + 0.3 * math.sin(yaw), yaw)  # 30 cm straight ahead, on the map
            accepted, _ = robot.navigate(*goal)
            assert accepted and drive_to_done(robot) == GoalStatus.SUCCEEDED
            pose = robot.get_pose()
            assert pose is not None and math.dist(pose[:2], goal[:2]) < 0.02
        finally:
            robot.close()


def test_the_docs_fleet_file_names_each_robot_and_places_it_on_the_map(children: list[Child], tmp_path: Path) -> None:
    """The fleet file of docs/open-rmf.md (its hosts replaced by simulated robots on free ports): one process of each
    kind for both robots, free_fleet's robots ``r1`` and ``r2`` each found at its own map_pose, and driven."""
    fleet = docs_toml_blocks()[1]["robot"]
    base = free_ports(2 * len(fleet))
    lines = []
    for n, robot in enumerate(fleet):
        lines += [
            "[[robot]]",
            f'id = "{robot["id"]}"',
            'host = "127.0.0.1"',
            f"control_port = {base + 2 * n}",
            f"log_port = {base + 2 * n + 1}",
            "[robot.nav]",
            f"map_pose = {robot['nav']['map_pose']}",
            "[robot.ros2]",
            f"rmf = {str(robot['ros2']['rmf']).lower()}",
            "",
        ]
    path = tmp_path / "fleet.toml"
    path.write_text("\n".join(lines))
    port = free_port()
    router = Child(["-m", "blackmetal", "router", "-l", f"tcp/127.0.0.1:{port}"])
    children.append(router)
    router.ready()
    started = [
        Child(["-m", "blackmetal", kind, "--fleet", str(path), *zenoh_connect_args(port)])
        for kind in ("sim", "gateway", "odometry", "nav", "ros2")
    ]
    for child in started:  # the simulator first: the gateways connect to its ports
        children.append(child)
        child.ready(timeout=60)
    with zenoh.open(client_config(port)) as session:
        for robot in fleet:
            robot_ready(session, f"fleet/{robot['id']}")
        adapters = {robot["id"]: FreeFleetRobot(session, robot["id"], service_call_timeout_sec=SERVICE_CALL_TIMEOUT_S) for robot in fleet}
        try:
            goals = {}
            for robot in fleet:  # RMF dispatches both robots at once: each goes to its own goal
                ff = adapters[robot["id"]]
                pose, _ = ff.initialize()
                x, y, yaw = robot["nav"]["map_pose"]
                assert (pose[0], pose[1]) == pytest.approx((x, y), abs=0.01) and angle(pose[2], yaw) < math.radians(1), (robot["id"], pose)
                goals[robot["id"]] = (x + 0.25 * math.cos(yaw), y + 0.25 * math.sin(yaw), yaw)
                accepted, _ = ff.navigate(*goals[robot["id"]])
                assert accepted, (robot["id"], ff.errors)
            for name, ff in adapters.items():
                assert drive_to_done(ff) == GoalStatus.SUCCEEDED, (name, ff.errors)
                pose = ff.get_pose()
                assert pose is not None and math.dist(pose[:2], goals[name][:2]) < 0.02, (name, pose, goals[name])
                print(f"free_fleet's {name}: reached {[round(v, 3) for v in pose]} (goal {[round(v, 3) for v in goals[name]]})")
                assert ff.errors == []
        finally:
            for ff in adapters.values():
                ff.close()


# ------------------------------------------------------------------ bad inputs on free_fleet's keys
def raw_send_goal(
    x: float, y: float, yaw_q: tuple[float, float, float, float], frame: str = "map", goal_id: list[int] | None = None
) -> bytes:
    """A send_goal request as free_fleet lays it out, with any values (NaN, infinities, any frame)."""

    now = time.time()
    return SendGoalRequest(
        goal_id=goal_id or list(range(16)),
        pose=PoseStamped(
            header=Header(stamp=Time(sec=int(now), nanosec=0), frame_id=frame),
            pose=ff.Pose(position=Point(x=x, y=y, z=0.0), orientation=Quaternion(*yaw_q)),
        ),
        behavior_tree="",
    ).serialize()


def test_bad_goals_on_free_fleets_keys_each_get_a_sentence_and_nothing_moves(site: zenoh.Session) -> None:

    errors: list[dict[str, Any]] = []
    site.declare_subscriber("robot/errors", lambda s: errors.append(json.loads(s.payload.to_bytes())))
    truth = Truth(site)
    key = "robot/navigate_to_pose/_action/"
    level = (0.0, 0.0, 0.0, 1.0)
    wait_for(lambda: truth.samples, what="the true pose")

    def ask(part: str, payload: bytes) -> list[Any]:
        return list(site.get(key + part, payload=payload, timeout=5))

    cases = {
        "x NaN": raw_send_goal(math.nan, 0.0, level),
        "y infinite": raw_send_goal(0.5, math.inf, level),
        "orientation NaN": raw_send_goal(0.5, 0.0, (0.0, 0.0, math.nan, 1.0)),
        "10 km away": raw_send_goal(10_000.0, 0.0, level),
        "another frame": raw_send_goal(0.5, 0.0, level, frame="earth"),
        "another robot's odometry": raw_send_goal(0.5, 0.0, level, frame="r9/odom"),
    }
    for what, payload in cases.items():
        # a request that decodes is answered, refused: an error reply would leave free_fleet without a goal id and
        # without a replan (it logs reply.err and moves on: the RMF task waits forever), and rmw_zenoh's client
        # drops error replies (the call never completes), where rclcpp_action's server answers accepted = false
        before = len(errors)
        replies = ask("send_goal", payload)
        oks = [r.ok for r in replies if r.ok is not None]
        assert len(oks) == 1, (what, [r.err.payload.to_string() for r in replies if r.err is not None])
        assert SendGoalResponse.deserialize(oks[0].payload.to_bytes()).accepted is False, what
        wait_for(lambda before=before: len(errors) > before, timeout=5, what=f"a sentence on robot/errors for a goal with {what}")
        print(f"{what}: {errors[before]['reason']}")
    garbage = {
        "empty": b"",
        "a header alone": b"\x00\x01\x00\x00",
        "cut short": raw_send_goal(0.5, 0.0, level)[:30],
        "not CDR": b'{"x": 1, "y": 2}',
        "a string where the pose is": b"\x00\x01\x00\x00" + bytes(16) + struct.pack("<I", 6) + b"hello\x00",
    }
    for what, payload in garbage.items():
        before = len(errors)
        replies = ask("send_goal", payload)
        for reply in replies:  # an error reply, or a refusal; never an acceptance
            if reply.ok is not None:
                assert SendGoalResponse.deserialize(reply.ok.payload.to_bytes()).accepted is False, what
        wait_for(lambda before=before: len(errors) > before, timeout=5, what=f"a sentence on robot/errors for a send_goal {what}")
        print(f"send_goal {what}: {'error reply' if any(r.err is not None for r in replies) else 'refused'}; {errors[before]['reason']}")
    # a cancel of a goal nobody knows, a result nobody has
    unknown = CancelGoalRequest(goal_info=GoalInfo(goal_id=UUID(uuid=[7] * 16), stamp=Time(sec=0, nanosec=0)))
    (reply,) = [r.ok for r in ask("cancel_goal", unknown.serialize()) if r.ok is not None]
    cancel = CancelGoalResponse.deserialize(reply.payload.to_bytes())
    assert cancel.return_code == 2 and cancel.goals_canceling == []  # ERROR_UNKNOWN_GOAL_ID
    (reply,) = [r.ok for r in ask("get_result", GetResultRequest(goal_id=[7] * 16).serialize()) if r.ok is not None]
    assert GetResultResponse.deserialize(reply.payload.to_bytes()).status == GoalStatus.UNKNOWN
    time.sleep(0.5)
    assert all(abs(p.v) < 1e-9 and abs(p.w) < 1e-9 for _, p in truth.samples), "the robot moved on a bad goal"
    assert all(e.get("reason") for e in errors)
    # and it still takes a good one
    robot = FreeFleetRobot(site, "robot", service_call_timeout_sec=SERVICE_CALL_TIMEOUT_S)
    try:
        robot.initialize()
        accepted, _ = robot.navigate(*on_map(0.2, 0.0, 0.0))
        assert accepted and drive_to_done(robot) == GoalStatus.SUCCEEDED
    finally:
        robot.close()


def test_a_flood_of_goals_is_answered_and_the_last_one_is_driven(site: zenoh.Session) -> None:
    """50 send_goal queries at once, as 50 impatient dispatchers: each answered, the last one accepted runs to
    SUCCEEDED, every other accepted one ends CANCELED (preempted)."""

    key = "robot/navigate_to_pose/_action/"
    answers: dict[int, list[bool]] = {}
    started = time.monotonic()
    for n in range(50):
        x, y, yaw = on_map(0.3 + 0.002 * n, 0.0, 0.0)
        payload = raw_send_goal(x, y, (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)), goal_id=[n] * 16)

        def on_reply(reply: Any, n: int = n) -> None:
            if reply.ok is not None:
                answers.setdefault(n, []).append(SendGoalResponse.deserialize(reply.ok.payload.to_bytes()).accepted)
            else:
                answers.setdefault(n, []).append(reply.err.payload.to_string())

        site.get(key + "send_goal", on_reply, payload=payload, timeout=10)
    try:
        wait_for(lambda: len(answers) == 50, timeout=15, what="an answer to each of the 50 goals")
    except AssertionError:
        # an unanswered send_goal is free_fleet's worst case: no goal id, no replan, the RMF task waits for ever
        raise AssertionError(f"send_goal queries never answered: {[n for n in range(50) if n not in answers]}") from None
    print(
        f"50 goals at once: all answered within {1000 * (time.monotonic() - started):.0f} ms, {sum(a == [True] for a in answers.values())} accepted"
    )
    accepted = sorted(n for n, a in answers.items() if a == [True])
    assert accepted, answers

    def status(n: int) -> int:
        (reply,) = [
            r.ok
            for r in site.get(key + "get_result", payload=GetResultRequest(goal_id=[n] * 16).serialize(), timeout=5)
            if r.ok is not None
        ]
        return int(GetResultResponse.deserialize(reply.payload.to_bytes()).status)

    live = (GoalStatus.ACCEPTED, GoalStatus.EXECUTING, GoalStatus.SUCCEEDED)

    def settled() -> dict[int, int] | None:
        """Every accepted goal's status once one alone lives (a preempted goal's end may take the adapter a moment to learn)."""
        statuses = {n: status(n) for n in accepted}
        return statuses if sum(s in live for s in statuses.values()) == 1 else None

    statuses = wait_for(settled, timeout=10, interval=0.5, what="one goal of the flood left running")
    (running,) = [n for n, s in statuses.items() if s in live]
    wait_for(lambda: status(running) == GoalStatus.SUCCEEDED, timeout=30, what="the goal that won to succeed")
    assert all(statuses[n] == GoalStatus.CANCELED for n in accepted if n != running), statuses


#: A robot that differs from the nominal constants (wheels 2 % long and 1.5 % short, a wider track) and whose motors
#: take time to reach a speed; its calibration, as blackmetal calibrate would find it.
DIFFERENT_ROBOT = ("--left-wheel-scale", "1.02", "--right-wheel-scale", "0.985", "--wheel-separation", "0.515", "--accel-limit", "1.5")
CALIBRATION = (
    "--impulses-left", str(model.IMPULSES_PER_METER_LEFT / 1.02),
    "--impulses-right", str(model.IMPULSES_PER_METER_RIGHT / 0.985),
    "--wheel-separation", "0.515",
)  # fmt: skip


@pytest.mark.parametrize("calibrated", [True, False], ids=["calibrated", "nominal constants"])
def test_free_fleet_on_a_robot_that_differs_from_its_nominal_constants(children: list[Child], calibrated: bool) -> None:
    """The goals free_fleet reads back are reached in the odometry either way (within 2 cm and 2 degrees on the map);
    the true robot is there too once calibrated, and off by its calibration error when not (printed)."""
    port = start_site(children, sim_args=DIFFERENT_ROBOT, constants=CALIBRATION if calibrated else ())
    with zenoh.open(client_config(port)) as session:
        robot_ready(session)
        truth = Truth(session)
        robot = FreeFleetRobot(session, "robot", service_call_timeout_sec=SERVICE_CALL_TIMEOUT_S)
        try:
            robot.initialize()
            for x, y, yaw in ((1.5, 0.4, 0.3), (0.2, -0.3, -2.5)):
                target = on_map(x, y, yaw)
                accepted, _ = robot.navigate(*target)
                assert accepted and drive_to_done(robot) == GoalStatus.SUCCEEDED, robot.errors
                pose = robot.get_pose()
                assert pose is not None and math.dist(pose[:2], target[:2]) < 0.02 and angle(pose[2], target[2]) < math.radians(2), (
                    pose,
                    target,
                )
                wait_for(lambda: not truth.moving(), what="the robot at rest")
                true = truth.samples[-1][1]
                off = math.dist((true.x, true.y), (x, y))
                print(f"{'calibrated' if calibrated else 'nominal constants'}: goal {(x, y)} (odometry frame), the true robot {1000 * off:.0f} mm "
                      f"and {math.degrees(angle(true.yaw, yaw)):.1f} deg from it")  # fmt: skip
                if calibrated:
                    assert off < 0.02 and angle(true.yaw, yaw) < math.radians(2)
            assert robot.errors == []
        finally:
            robot.close()


# ------------------------------------------------------------------ with free_fleet's own pinned packages
#: free_fleet's README: ``pip3 install nudged eclipse-zenoh==1.5.0 pycdr2 rosbags``; the adapter's Zenoh and CDR are these.
FREE_FLEET_PACKAGES = ("eclipse-zenoh==1.5.0", "pycdr2")


@pytest.fixture(scope="session")
def free_fleet_python(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A virtualenv with free_fleet's pinned Zenoh and pycdr2 from PyPI; its interpreter (skipped only when PyPI cannot be reached)."""
    import subprocess
    import venv

    root = tmp_path_factory.mktemp("free-fleet-venv")
    venv.EnvBuilder(with_pip=True).create(root / "venv")
    python = str(root / "venv" / "bin" / "python")
    pip = [python, "-m", "pip", "--disable-pip-version-check", "-q"]
    installed = subprocess.run([*pip, "install", *FREE_FLEET_PACKAGES], capture_output=True, text=True, timeout=600)
    if installed.returncode != 0:
        probe = subprocess.run([*pip, "download", "--no-deps", "-d", str(root / "probe"), "pycdr2"], capture_output=True, timeout=300)
        if probe.returncode != 0:
            pytest.skip("PyPI cannot be reached, so free_fleet's pinned packages cannot be installed.")
        raise AssertionError(f"pip install {' '.join(FREE_FLEET_PACKAGES)} failed:\n{installed.stdout}\n{installed.stderr}")
    return python


def test_free_fleets_own_zenoh_version_drives_the_robot(children: list[Child], free_fleet_python: str) -> None:
    """The same calls through eclipse-zenoh 1.5.0 (free_fleet's pin), a client of the site's router: the robot found,
    a goal accepted and read back SUCCEEDED, a far goal stopped by RMF's cancel-all."""
    import os
    import subprocess

    port = start_site(children)
    with zenoh.open(client_config(port)) as session:
        robot_ready(session)
    target = on_map(0.4, 0.2, 0.5)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    script = Path(__file__).resolve().parents[1] / "free_fleet_run.py"
    ran = subprocess.run(
        [free_fleet_python, str(script), str(port), "robot", *map(str, target)], capture_output=True, text=True, timeout=180, env=env
    )
    assert ran.returncode == 0, ran.stderr[-3000:]
    out = json.loads(ran.stdout.strip().splitlines()[-1])
    print(f"free_fleet with eclipse-zenoh {out['zenoh']}, pycdr2 {out['pycdr2']}: found after {out['found_after_s']:.1f} s, "
          f"accepted in {1000 * out['accepted_in_s']:.1f} ms, {out['status']}, cancel-all {out['cancel_codes']}")  # fmt: skip
    assert out["zenoh"] == "1.5.0"
    assert out["accepted"] is True and out["status"] == "SUCCEEDED"  # its timing: printed (a new process's first query)
    assert math.dist(out["end_pose"][:2], target[:2]) < 0.02 and angle(out["end_pose"][2], target[2]) < math.radians(2)
    assert out["far_accepted"] is True and out["cancel_codes"] == [0]
    assert out["feedback_count"] > 5 and out["battery_soc"] == 1.0 and out["errors"] == []


def test_the_navigation_service_restarting_mid_goal_as_free_fleet_sees_it(children: list[Child]) -> None:
    """The navigation process dies while free_fleet's goal runs: the robot stops (the gateway's command timeout ends
    nav's last command); within 10 s free_fleet's get_result says the goal ended (ABORTED, or UNKNOWN to a new
    navigation), so that RMF replans (a goal left EXECUTING holds its task for ever); a new navigation drives no old
    goal, and free_fleet's next goal drives again."""
    port = start_site(children)
    (nav,) = [c for c in children if c.args[2:3] == ["nav"]]
    with zenoh.open(client_config(port)) as session:
        robot_ready(session)
        truth = Truth(session)
        robot = FreeFleetRobot(session, "robot", service_call_timeout_sec=SERVICE_CALL_TIMEOUT_S)
        try:
            robot.initialize()
            accepted, _ = robot.navigate(*on_map(3.0, 0.0, 0.0))
            assert accepted
            wait_for(truth.moving, what="the robot driving")
            since = time.monotonic()
            nav.proc.kill()  # a crash: no last zero command
            nav.proc.wait(10)
            stopped = wait_for(lambda: truth.stopped_after(since), timeout=5, what="the robot stopped without its navigation")
            assert stopped < 1.0  # the gateway's command timeout (0.5 s) and a poll
            # free_fleet asks at each update; a goal left EXECUTING for ever would hold RMF's task for ever
            robot.last_feedback = None
            seen = [robot.is_navigation_done()[1]]
            ended = (GoalStatus.ABORTED, GoalStatus.UNKNOWN, GoalStatus.CANCELED)
            deadline = time.monotonic() + 10
            while seen[-1] not in ended and time.monotonic() < deadline:
                time.sleep(UPDATE_PERIOD_S)
                seen.append(robot.is_navigation_done()[1])
            print(
                f"navigation gone mid-goal: the robot stopped after {1000 * stopped:.0f} ms; free_fleet's get_result said {seen[0]!r}, then {seen[-1]!r}"
            )
            restarted = Child(["-m", "blackmetal", *nav.args[2:]])
            children.append(restarted)
            restarted.ready(timeout=60)
            time.sleep(0.5)
            assert not truth.moving(), "a new navigation drove an old goal"
            after = robot.is_navigation_done()[1]
            print(f"and once a new navigation is up: {after!r}")
            assert seen[-1] in ended, f"the goal of a navigation that died was still {seen[-1]!r} after 10 s: free_fleet never replans"
            assert after in ended
            accepted, _ = robot.navigate(*on_map(0.3, 0.0, 0.0))
            assert accepted and drive_to_done(robot) == GoalStatus.SUCCEEDED
        finally:
            robot.close()
