"""A Black Metal robot dispatched by Open-RMF's free_fleet, as its unmodified Nav2 robot adapter would (issue #39).

The client is tests/free_fleet_client.py: free_fleet's ``Nav2RobotAdapter`` call for call (its keys,
its CDR layouts written with pycdr2, its timeouts, its tf2 lookup of ``map -> base_footprint`` from
``<robot>/tf`` alone), with RMF itself left out. The robot is what a site runs: a Zenoh router, the
simulator, the gateway, the odometry, the navigation service and ``blackmetal ros2 --rmf`` (the plain
zenoh-bridge-ros2dds key format under the robot's RMF name, ``robot`` for the prefix ``robot``), all
clients of the router, as free_fleet's fleet adapter is. The map frame is placed over the odometry
frame by ``nav --map-pose``, so every pose free_fleet reads is on the map.

Figures printed: how long free_fleet waited for the robot's pose, each send_goal's round trip (accepted
within 50 ms), the feedback rate, and how long after a cancel-all the simulator's true speed was zero
(within 100 ms).
"""

from __future__ import annotations

import json
import math
import re
import statistics
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
import zenoh
from free_fleet_client import (
    FreeFleetRobot,
    GoalStatus,
    TFMessage,
    yaw_from_quaternion,
)
from helpers import Child, SimProcess, client_config, free_port, wait_for, zenoh_connect_args

from blackmetal.schemas import Pose, decode

pytestmark = pytest.mark.integration

#: Where the odometry frame sits on the map (x, y, yaw): the robot starts at the odometry frame's origin.
MAP_POSE = (1.5, -0.75, 0.5)
#: free_fleet_examples' nav2_tb3_simulation_fleet_config.yaml: the example robot's service call timeout and its
#: update loop (robot_state_update_frequency).
SERVICE_CALL_TIMEOUT_S = 1.0
UPDATE_PERIOD_S = 0.1


def start_site(
    children: list[Child], *ros2_args: str, prefix: str = "robot", sim_args: tuple[str, ...] = (), constants: tuple[str, ...] = ()
) -> int:
    """A router, and the robot's processes under ``prefix`` as its clients (``constants``: the gateway's and the
    odometry's robot constants); the router's port."""
    port = free_port()
    router = Child(["-m", "blackmetal", "router", "-l", f"tcp/127.0.0.1:{port}"])
    children.append(router)
    router.ready()
    sim = SimProcess("--prefix", prefix, *sim_args, *zenoh_connect_args(port))
    children.append(sim)
    robot = [
        ["gateway", "--control-port", str(sim.control_port), "--log-port", str(sim.log_port), *constants],
        ["odometry", *constants],
        ["nav", "--map-pose=" + ",".join(map(str, MAP_POSE))],
        ["ros2", "--rmf", *ros2_args],
    ]
    started = [Child(["-m", "blackmetal", *args, "--prefix", prefix, *zenoh_connect_args(port)]) for args in robot]
    children.extend(started)
    for child in started:
        child.ready(timeout=60)
    return port


def robot_ready(session: zenoh.Session, prefix: str = "robot") -> None:
    """Until the gateway's control link is up: before that the navigation refuses goals ("robot unreachable: the
    gateway's control link is connecting"), which free_fleet would meet with a replan."""
    health: list[dict[str, Any]] = []
    sub = session.declare_subscriber(f"{prefix}/gateway/health", lambda s: health.append(json.loads(s.payload.to_bytes())))
    try:
        wait_for(lambda: health and health[-1]["control"]["state"] == "connected", what=f"{prefix}'s control link connected")
        time.sleep(0.3)  # the navigation service reads the same health
    finally:
        sub.undeclare()


@pytest.fixture
def site(children: list[Child]) -> Iterator[zenoh.Session]:
    port = start_site(children)
    with zenoh.open(client_config(port)) as session:
        robot_ready(session)
        yield session


class Truth:
    """The simulator's true pose, as it arrives (time.monotonic(), Pose)."""

    def __init__(self, session: zenoh.Session) -> None:
        self.samples: list[tuple[float, Pose]] = []
        self._sub = session.declare_subscriber(
            "robot/sim/truth", lambda s: self.samples.append((time.monotonic(), decode(Pose, s.payload.to_bytes())))
        )

    def moving(self) -> bool:
        return bool(self.samples) and abs(self.samples[-1][1].v) > 0.05

    def stopped_after(self, since: float) -> float | None:
        """Seconds from ``since`` to the first true pose after it with no speed at all."""
        for arrived, pose in list(self.samples):
            if arrived >= since and abs(pose.v) < 1e-9 and abs(pose.w) < 1e-9:
                return arrived - since
        return None


def on_map(x: float, y: float, yaw: float) -> tuple[float, float, float]:
    """An odometry-frame pose on the map (map -> odom is MAP_POSE)."""
    mx, my, myaw = MAP_POSE
    return (mx + x * math.cos(myaw) - y * math.sin(myaw), my + x * math.sin(myaw) + y * math.cos(myaw), myaw + yaw)


def angle(a: float, b: float) -> float:
    return abs(math.remainder(a - b, math.tau))


def drive_to_done(robot: FreeFleetRobot, timeout: float = 60.0, each: Callable[[], None] | None = None) -> GoalStatus | None:
    """free_fleet's update loop: ``_is_navigation_done`` every update period until it says done; the status it read
    (``each``: called every update, as free_fleet reads the pose for RMF's robot state)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if each is not None:
            each()
        done, status = robot.is_navigation_done()
        if done:
            return status
        if status == GoalStatus.ABORTED:
            why = [r.ok.payload.to_string() for r in robot.session.get("**/nav/result", timeout=2) if r.ok is not None]
            print(f"free_fleet's goal ABORTED; the navigation's results: {why}")  # the reason, for whoever reads the failure
            return status
        time.sleep(UPDATE_PERIOD_S)
    raise AssertionError(f"free_fleet's goal did not end in {timeout:.0f} s; errors: {robot.errors}")


# ------------------------------------------------------------------ the tests
def test_free_fleet_finds_the_robot_on_the_map_from_tf_alone_and_assumes_a_full_battery(site: zenoh.Session) -> None:
    battery: list[Any] = []
    site.declare_subscriber("robot/battery_state", battery.append)
    robot = FreeFleetRobot(site, "robot", service_call_timeout_sec=SERVICE_CALL_TIMEOUT_S)
    try:
        pose, took = robot.initialize()  # RuntimeError after init_timeout_sec (10 s), as free_fleet gives up
        print(f"free_fleet had the robot's pose (map -> base_footprint from robot/tf) after {took:.1f} s: {pose}")
        assert (pose[0], pose[1]) == pytest.approx(MAP_POSE[:2], abs=0.01)
        assert angle(pose[2], MAP_POSE[2]) < math.radians(1)
        # the pose keeps resolving as tf keeps coming (map -> odom goes with every odom -> base_footprint)
        time.sleep(2.0)
        assert robot.get_pose() is not None, robot.last_lookup_error
        assert robot.tf_samples > 50
        assert battery == [] and robot.battery_soc == 1.0  # no battery gauge: nothing published, free_fleet's 1.0
        assert robot.errors == []
    finally:
        robot.close()


def test_free_fleet_goals_accepted_fast_succeeded_read_back_and_preempted(site: zenoh.Session) -> None:
    robot = FreeFleetRobot(site, "robot", service_call_timeout_sec=SERVICE_CALL_TIMEOUT_S)
    odometry: list[Pose] = []
    site.declare_subscriber("robot/pose", lambda s: odometry.append(decode(Pose, s.payload.to_bytes())))
    behind: list[float] = []  # how far the pose free_fleet reads is from the odometry's latest, on the map (m)

    def compare() -> None:  # free_fleet's get_pose for RMF's robot state, at each update
        pose = robot.get_pose()
        if pose is not None and odometry:
            latest = odometry[-1]
            behind.append(math.dist(pose[:2], on_map(latest.x, latest.y, latest.yaw)[:2]))

    try:
        robot.initialize()
        accepted_in: list[float] = []
        goals = [(0.8, 0.3, 0.6), (0.2, -0.4, -1.2), (0.0, 0.0, 0.0)]  # odometry frame; sent on the map
        for x, y, yaw in goals:
            target = on_map(x, y, yaw)
            accepted, call = robot.navigate(*target)
            assert accepted is True, (call, robot.errors)
            accepted_in.append(call.elapsed)
            first_feedback = len(robot.feedback_times)
            status = drive_to_done(robot, each=compare)
            assert status == GoalStatus.SUCCEEDED, (status, robot.errors)
            pose = robot.get_pose()
            assert pose is not None, robot.last_lookup_error
            assert math.dist(pose[:2], target[:2]) < 0.02 and angle(pose[2], target[2]) < math.radians(2), (pose, target)
            assert robot.last_feedback is not None and bytes(robot.last_feedback[0].goal_id) == bytes(robot.goal_id or [])
            feedback = robot.feedback_times[first_feedback:]
            rate = (len(feedback) - 1) / (feedback[-1] - feedback[0]) if len(feedback) > 1 else 0.0
            print(f"goal {target}: accepted in {1000 * call.elapsed:.1f} ms, feedback {rate:.1f} Hz, got SUCCEEDED")
            assert rate >= 5.0
        # free_fleet's navigate while a goal runs: cancel-all, then the new goal (the first one ends CANCELED)
        accepted, _ = robot.navigate(*on_map(3.0, 0.0, 0.0))
        assert accepted
        first = list(robot.goal_id or [])
        time.sleep(0.5)
        accepted, call = robot.navigate(*on_map(0.1, 0.1, 0.0))
        assert accepted and robot.calls[-2].key.endswith("/cancel_goal")
        accepted_in.append(call.elapsed)
        assert drive_to_done(robot) == GoalStatus.SUCCEEDED
        robot.goal_id = first
        robot.last_feedback = None
        assert robot.is_navigation_done() == (True, GoalStatus.CANCELED)
        print("send_goal round trips (ms):", [round(1000 * t, 1) for t in accepted_in])
        print(
            f"the pose free_fleet read while driving: median {1000 * statistics.median(behind):.1f} mm, at most "
            f"{1000 * max(behind):.1f} mm from the odometry's latest ({len(behind)} reads)"
        )
        # tf's latest common time is the latest pose: nothing old (a map -> odom stamped apart would lag by its
        # period, and fall out of tf2's 10 s cache); the max leaves room for a loaded machine's scheduling
        assert len(behind) > 20 and statistics.median(behind) < 0.01 and max(behind) < 0.06
        # the bar (50 ms) on the typical goal; a loaded 2-core machine may hold one reply back, never by much
        assert statistics.median(accepted_in) <= 0.050 and max(accepted_in) <= 0.100, accepted_in
        assert robot.errors == []
    finally:
        robot.close()


def test_free_fleet_cancel_all_stops_the_robot_within_100_ms(site: zenoh.Session) -> None:
    truth = Truth(site)
    robot = FreeFleetRobot(site, "robot", service_call_timeout_sec=SERVICE_CALL_TIMEOUT_S)
    try:
        robot.initialize()
        stops = []
        for distance in (3.0, -3.0):
            accepted, _ = robot.navigate(*on_map(distance, 0.5, 0.0))
            assert accepted, robot.errors
            wait_for(truth.moving, what="the robot driving to free_fleet's goal")
            time.sleep(0.7)  # well under way
            assert truth.moving()
            since = time.monotonic()
            codes = robot.stop()  # RMF's stop(): cancel-all, a zero goal id and stamp
            assert codes == [0], codes  # ERROR_NONE: the running goal is canceling
            stopped = wait_for(lambda since=since: truth.stopped_after(since), timeout=5, what="the true speed at zero")
            stops.append(stopped)
            print(f"cancel-all: reply in {1000 * robot.calls[-1].elapsed:.1f} ms, the robot's true speed 0 after {1000 * stopped:.0f} ms")
            time.sleep(0.5)
            assert all(abs(p.v) < 1e-9 for t, p in truth.samples if t > since + stopped), "the robot moved again after the cancel"
        assert max(stops) <= 0.100, stops
        assert robot.stop() == []  # nothing held: free_fleet sends nothing
        assert robot.cancel_all() in ([0], [1], [3])  # nothing running: some return code, never a crash
        assert robot.errors == []
    finally:
        robot.close()


def test_free_fleet_goal_refused_while_the_e_stop_is_engaged(site: zenoh.Session) -> None:
    errors: list[str] = []
    health: list[dict[str, Any]] = []
    site.declare_subscriber("robot/errors", lambda s: errors.append(s.payload.to_string()))
    site.declare_subscriber("robot/gateway/health", lambda s: health.append(json.loads(s.payload.to_bytes())))
    truth = Truth(site)
    robot = FreeFleetRobot(site, "robot", service_call_timeout_sec=SERVICE_CALL_TIMEOUT_S)
    try:
        robot.initialize()
        site.put("robot/estop", json.dumps({"engaged": True}))
        wait_for(lambda: health and health[-1].get("estop"), what="the e-stop engaged in the gateway's health")
        time.sleep(0.3)  # the navigation service reads the same health
        accepted, _ = robot.navigate(*on_map(1.0, 0.0, 0.0))
        assert accepted is False and robot.goal_id is None
        wait_for(lambda: any(re.search(r"e-?stop", e, re.I) for e in errors), what="the refusal's sentence on robot/errors")
        print("refused:", [e for e in errors if re.search(r"e-?stop", e, re.I)][:2])
        time.sleep(0.5)
        assert not truth.moving()
        site.put("robot/estop/release", json.dumps({"engaged": False}))
        wait_for(lambda: health and not health[-1].get("estop"), what="the e-stop released")
        time.sleep(0.5)
        assert not truth.moving(), "something moved after the release with no goal"
        accepted, _ = robot.navigate(*on_map(0.3, 0.0, 0.0))
        assert accepted and drive_to_done(robot) == GoalStatus.SUCCEEDED
        assert robot.errors == []
    finally:
        robot.close()


def test_an_e_stop_during_free_fleets_goal_aborts_it_and_nothing_moves_after_the_release(site: zenoh.Session) -> None:
    """free_fleet reads ABORTED (it files an issue ticket and RMF replans); the reason is the navigation's
    (``robot/nav/result``); after the release the robot stays put until RMF sends a new goal."""
    health: list[dict[str, Any]] = []
    site.declare_subscriber("robot/gateway/health", lambda s: health.append(json.loads(s.payload.to_bytes())))
    truth = Truth(site)
    robot = FreeFleetRobot(site, "robot", service_call_timeout_sec=SERVICE_CALL_TIMEOUT_S)
    try:
        robot.initialize()
        accepted, _ = robot.navigate(*on_map(2.5, 0.0, 0.0))
        assert accepted
        wait_for(truth.moving, what="the robot driving to free_fleet's goal")
        time.sleep(0.5)
        since = time.monotonic()
        site.put("robot/estop", json.dumps({"engaged": True}))
        stopped = wait_for(lambda: truth.stopped_after(since), timeout=5, what="the robot stopped by the e-stop")
        robot.last_feedback = None  # free_fleet asks at its next update once the feedback says the goal is due
        done, _ = wait_for(lambda: (r := robot.is_navigation_done())[1] == GoalStatus.ABORTED and r, timeout=10, what="ABORTED")
        assert done is False  # free_fleet: an issue ticket and a replan, the goal id kept until RMF sends another
        results = [json.loads(r.ok.payload.to_bytes()) for r in site.get("robot/nav/result", timeout=5) if r.ok is not None]
        assert results and results[0]["state"] == "aborted" and re.search(r"e-?stop", results[0]["reason"], re.I), results
        print(f"e-stop during free_fleet's goal: the true speed 0 after {1000 * stopped:.0f} ms; ABORTED: {results[0]['reason']}")
        site.put("robot/estop/release", json.dumps({"engaged": False}))
        wait_for(lambda: health and not health[-1].get("estop"), what="the e-stop released")
        released = time.monotonic()
        time.sleep(1.5)
        assert all(abs(p.v) < 1e-9 and abs(p.w) < 1e-9 for t, p in truth.samples if t > released), "the robot moved after the release"
        accepted, _ = robot.navigate(*on_map(0.3, 0.0, 0.0))  # RMF's replan: a new goal, which drives again
        assert accepted and drive_to_done(robot) == GoalStatus.SUCCEEDED
        assert robot.errors == []
    finally:
        robot.close()


def test_a_fleet_robot_is_named_by_its_prefixs_last_chunk_and_its_battery_gauge_reaches_free_fleet(children: list[Child]) -> None:
    """Prefix ``fleet/bm_1``: free_fleet's robot ``bm_1`` (keys ``bm_1/...``); ``--rmf-battery``: ``bm_1/battery_state``,
    of which free_fleet reads ``percentage``."""
    port = start_site(children, "--rmf-battery", "0.42", prefix="fleet/bm_1")
    with zenoh.open(client_config(port)) as session:
        robot_ready(session, "fleet/bm_1")
        robot = FreeFleetRobot(session, "bm_1", service_call_timeout_sec=SERVICE_CALL_TIMEOUT_S)
        try:
            pose, _ = robot.initialize()
            assert (pose[0], pose[1]) == pytest.approx(MAP_POSE[:2], abs=0.01)
            wait_for(lambda: robot.battery_soc != 1.0, what="bm_1/battery_state at free_fleet")
            assert robot.battery_soc == pytest.approx(0.42, abs=1e-6)  # float32
            accepted, _ = robot.navigate(*on_map(0.4, 0.0, 0.0))
            assert accepted and drive_to_done(robot) == GoalStatus.SUCCEEDED
            assert robot.errors == []
        finally:
            robot.close()


def test_what_free_fleet_reads_from_the_robots_tf(site: zenoh.Session) -> None:
    """The frames are not prefixed (free_fleet prefixes them itself with the robot's name), and map -> odom comes in
    the same messages as odom -> base_footprint, with the same stamp: tf2's lookup is at the latest common time of
    the chain, so an older map -> odom would give free_fleet an old pose (and none once it fell out of the 10 s cache)."""

    seen: list[Any] = []
    site.declare_subscriber("robot/tf", lambda s: seen.append(TFMessage.deserialize(s.payload.to_bytes())))
    wait_for(lambda: len(seen) >= 10, what="robot/tf")
    pairs = {(t.header.frame_id, t.child_frame_id) for m in seen for t in m.transforms}
    assert {("map", "odom"), ("odom", "base_footprint")} <= pairs, pairs
    for message in seen:
        stamps = {(t.header.stamp.sec, t.header.stamp.nanosec) for t in message.transforms if t.header.frame_id in ("map", "odom")}
        assert len(stamps) == 1, stamps
    map_odom = next(t for m in seen for t in m.transforms if t.child_frame_id == "odom").transform
    assert (map_odom.translation.x, map_odom.translation.y) == pytest.approx(MAP_POSE[:2])
    r = map_odom.rotation
    assert yaw_from_quaternion(r.x, r.y, r.z, r.w) == pytest.approx(MAP_POSE[2])
