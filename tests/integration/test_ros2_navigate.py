"""ROS 2's ``navigate_to_pose`` action on a Black Metal robot, as ``ros2 action send_goal`` and Nav2's clients use it (issue #39).

The client is tests/rmw_action_client.py, written from rcl_action's, rmw_zenoh's and rosidl's sources
(not from our adapter): a Humble client (``TypeHashNotSupported``) and a Jazzy client (RIHS01 hashes it
computes from the genuine definitions in tests/ros2_interfaces/), each with its liveliness tokens, its
33-byte attachments and CDR built from the ``.action``. The robot is ``blackmetal up --ros2`` (the
simulator, gateway, odometry, navigation service and the ROS 2 adapter) as a client of a router started
with rmw_zenoh's router config, as the ROS side deploys it.

Figures printed: send_goal round trips, the feedback rate per distro, how long after a cancel the
simulator's true speed was zero.
"""

from __future__ import annotations

import json
import math
import re
import time
from collections.abc import Iterator
from typing import Any

import pytest
import xxhash
import zenoh
from helpers import Child, client_config, wait_for
from rmw_action_client import (
    CANCEL_CODES,
    STATUS,
    ActionClient,
    TopicPublisher,
    quaternion_from_yaw,
    rate,
    read_attachment,
    stamped_now,
    yaw_of,
)

from blackmetal.schemas import Pose, decode
from integration.test_ros2_sdk import ros_graph

pytestmark = pytest.mark.integration

SUCCEEDED, CANCELED, UNKNOWN = 4, 5, 0


def robot_ready(session: zenoh.Session, prefix: str = "robot") -> None:
    """Until the gateway's control link is up: before that the navigation refuses goals ("robot unreachable: the
    gateway's control link is connecting"), as it should, and ``up`` is ready before the link is."""
    health: list[dict[str, Any]] = []
    sub = session.declare_subscriber(f"{prefix}/gateway/health", lambda s: health.append(json.loads(s.payload.to_bytes())))
    try:
        wait_for(lambda: health and health[-1]["control"]["state"] == "connected", what=f"{prefix}'s control link connected")
        time.sleep(0.3)  # the navigation service reads the same health
    finally:
        sub.undeclare()


@pytest.fixture
def graph(children: list[Child]) -> Iterator[zenoh.Session]:
    """``up --ros2 --distro humble,jazzy``: one node per distro, one robot, one navigation service."""
    port = ros_graph(children, "--distro", "humble,jazzy")
    with zenoh.open(client_config(port)) as session:
        robot_ready(session)
        yield session


def clients(session: zenoh.Session, distros: tuple[str, ...] = ("humble", "jazzy")) -> dict[str, ActionClient]:
    """An action client per distro, once the server is in the graph for it (``wait_for_action_server``)."""
    made = {distro: ActionClient(session, distro, node=f"{distro}_navigate_client") for distro in distros}
    for distro, client in made.items():
        wait_for(client.server_is_available, timeout=30, interval=0.5, what=f"the {distro} action server's three services and two topics")
    return made


class Truth:
    def __init__(self, session: zenoh.Session, key: str = "robot/sim/truth") -> None:
        self.samples: list[tuple[float, Pose]] = []
        self._sub = session.declare_subscriber(key, lambda s: self.samples.append((time.monotonic(), decode(Pose, s.payload.to_bytes()))))

    def moving(self) -> bool:
        return bool(self.samples) and abs(self.samples[-1][1].v) > 0.05

    def stopped_after(self, since: float) -> float | None:
        for arrived, pose in list(self.samples):
            if arrived >= since and abs(pose.v) < 1e-9 and abs(pose.w) < 1e-9:
                return arrived - since
        return None


def angle(a: float, b: float) -> float:
    return abs(math.remainder(a - b, math.tau))


def test_send_goal_feedback_and_result_on_humble_and_jazzy_keys(graph: zenoh.Session) -> None:
    made = clients(graph)
    truth = Truth(graph)
    try:
        goals = {"jazzy": (0.6, 0.2, 0.8), "humble": (0.0, 0.0, 0.0)}
        for distro, (x, y, yaw) in goals.items():
            client = made[distro]
            goal_id, reply = client.send_goal(x, y, yaw, frame="map")
            assert reply.message["accepted"] is True, reply
            assert reply.sequence >= 1 and reply.gid == client.gids["send_goal"]  # rmw_zenoh: our sequence and GID back
            result = client.get_result(goal_id, timeout=60)  # held until the goal ends, as rmw_zenoh's client waits
            assert result.message["status"] == SUCCEEDED, (STATUS.get(result.message["status"]), result.message)
            if distro == "jazzy":
                assert result.message["result"] == {"error_code": 0, "error_msg": ""}
            else:
                assert result.message["result"] == {"result": {"structure_needs_at_least_one_member": 0}}  # std_msgs/Empty
            end = truth.samples[-1][1]
            assert math.dist((end.x, end.y), (x, y)) < 0.03 and angle(end.yaw, yaw) < math.radians(3), (end, (x, y, yaw))
            for name, other in made.items():  # each node publishes the goal's feedback on its own distro's key
                times = [t for t, _ in other.feedback_of(goal_id)]
                print(
                    f"{distro} goal: accepted in {1000 * reply.elapsed:.1f} ms; its feedback on {name}'s key: {len(times)} at {rate(times):.1f} Hz"
                )
                assert rate(times) >= 5.0
            last = client.feedback_of(goal_id)[-1][1]
            assert last["current_pose"]["header"]["frame_id"] == "map"
            assert yaw_of(last["current_pose"]["pose"]["orientation"]) == pytest.approx(yaw, abs=math.radians(5))
            wait_for(
                lambda c=client, g=goal_id: c.status_of(g)[-1:] == [SUCCEEDED], timeout=5, what=f"SUCCEEDED in the {distro} status array"
            )
            assert set(client.status_of(goal_id)) <= {1, 2, 4}, client.status_of(goal_id)
            assert reply.elapsed <= 1.0, reply.elapsed  # the first request of a client sets its routes up; printed above
        for distro, client in made.items():  # the feedback publisher's attachment: its sequence and its GID, the hash of its token
            attachments = [read_attachment(raw) for _, _, raw in client.feedback if raw is not None]
            assert len(attachments) == len(client.feedback) and [a[0] for a in attachments] == sorted({a[0] for a in attachments})
            (token,) = [t for t in client.server_tokens() if t.split("/")[5] == "MP" and t.split("/")[9] == "%navigate_to_pose%_action%feedback"
                        and t.split("/")[11] == client.type_hash(client.types["feedback"])]  # fmt: skip
            assert {a[2] for a in attachments} == {xxhash.xxh3_128_intdigest(token.encode()).to_bytes(16, "little")}, distro
            assert client.errors == []
    finally:
        for client in made.values():
            client.close()


def test_cancel_on_each_distro_stops_the_robot_and_ends_the_goal_canceled(graph: zenoh.Session) -> None:
    made = clients(graph)
    truth = Truth(graph)
    try:
        for distro, distance in (("jazzy", 3.0), ("humble", -3.0)):
            client = made[distro]
            goal_id, reply = client.send_goal(distance, 0.0, 0.0)
            assert reply.message["accepted"]
            pending = client.get_result_async(goal_id)
            wait_for(truth.moving, what="the robot driving to the goal")
            wait_for(
                lambda c=client, g=goal_id: 2 in c.status_of(g), what=f"the goal EXECUTING in /navigate_to_pose/_action/status ({distro})"
            )
            time.sleep(0.5)
            since = time.monotonic()
            canceled = client.cancel(goal_id)
            assert CANCEL_CODES[canceled.message["return_code"]] == "ERROR_NONE", canceled.message
            assert [bytes(g["goal_id"]["uuid"]) for g in canceled.message["goals_canceling"]] == [goal_id]
            stopped = wait_for(lambda s=since: truth.stopped_after(s), timeout=5, what="the true speed at zero")
            pending["thread"].join(30)
            assert "reply" in pending, pending.get("error")
            assert pending["reply"].message["status"] == CANCELED
            print(f"{distro}: cancel answered in {1000 * canceled.elapsed:.1f} ms, the robot's true speed 0 after {1000 * stopped:.0f} ms")
            assert stopped <= 0.25
            assert client.status_of(goal_id)[-1] == CANCELED
        # cancel-all (zero id, zero stamp) with nothing running, a goal nobody knows, a result nobody has
        humble, jazzy = made["humble"], made["jazzy"]
        assert humble.cancel().message["goals_canceling"] == []
        unknown = bytes(range(16))
        assert CANCEL_CODES[jazzy.cancel(unknown).message["return_code"]] == "ERROR_UNKNOWN_GOAL_ID"
        started = time.monotonic()
        assert jazzy.get_result(unknown, timeout=10).message["status"] == UNKNOWN
        assert time.monotonic() - started < 2.0  # answered at once, not held
        # a cancel-all while a goal runs (Humble's ``ros2 action send_goal`` Ctrl-C is a cancel of its goal; Nav2's
        # clients and free_fleet cancel all)
        goal_id, reply = humble.send_goal(2.0, 0.0, 0.0)
        wait_for(truth.moving, what="the robot driving again")
        canceled = humble.cancel()
        assert [bytes(g["goal_id"]["uuid"]) for g in canceled.message["goals_canceling"]] == [goal_id]
        wait_for(lambda: humble.get_result(goal_id, timeout=10).message["status"] == CANCELED, what="the goal canceled")
        for client in made.values():
            assert client.errors == []
    finally:
        for client in made.values():
            client.close()


def test_a_late_status_subscriber_gets_the_last_goal_statuses(graph: zenoh.Session) -> None:
    """The status topic is transient local (rcl_action's status QoS, depth 1): a client that joins after the goal
    ended still reads its final status from the publisher's cache."""
    first = clients(graph, ("jazzy",))["jazzy"]
    try:
        goal_id, reply = first.send_goal(0.2, 0.0, 0.0)
        assert reply.message["accepted"]
        assert first.get_result(goal_id, timeout=60).message["status"] == SUCCEEDED
    finally:
        first.close()
    time.sleep(1.0)
    for distro in ("jazzy", "humble"):
        late = ActionClient(graph, distro, node=f"late_{distro}_client")
        try:
            wait_for(lambda late=late: late.statuses, timeout=10, what=f"the {distro} status array from the publisher's cache")
            assert late.status_of(goal_id)[-1] == SUCCEEDED
        finally:
            late.close()


def test_bad_goals_are_answered_refused(graph: zenoh.Session) -> None:
    """A goal that decodes gets its answer, accepted = false, with the reason on robot/errors: rmw_zenoh's client drops
    an error reply (``z_reply_is_ok returned False``) and ``ros2 action send_goal`` would wait for ever, where
    rclcpp_action's server answers a goal its handler rejects."""
    errors: list[str] = []
    graph.declare_subscriber("robot/errors", lambda s: errors.append(json.loads(s.payload.to_bytes())["reason"]))
    client = clients(graph, ("jazzy",))["jazzy"]
    try:
        level = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
        for what, (x, y, orientation, frame) in {
            "x NaN": (math.nan, 0.0, level, "map"),
            "an infinite orientation": (0.5, 0.0, {**level, "z": math.inf}, "map"),
            "10 km away": (10_000.0, 0.0, level, "map"),
            "another frame": (0.5, 0.0, level, "earth"),
        }.items():
            before = len(errors)
            _, reply = client.send_goal(x, y, 0.0, frame=frame, orientation=orientation)
            assert reply.message["accepted"] is False, what
            wait_for(lambda before=before: len(errors) > before, timeout=5, what=f"the reason for the goal with {what}")
            print(f"{what}: {errors[before]}")
        goal_id, reply = client.send_goal(0.2, 0.0, 0.0)
        assert reply.message["accepted"] and client.get_result(goal_id, timeout=60).message["status"] == SUCCEEDED
    finally:
        client.close()


def test_each_robot_of_a_fleet_has_its_own_action_under_its_namespace(children: list[Child]) -> None:
    """``up --robots 2 --ros2``: a node per robot, the action at ``/r2/navigate_to_pose`` (keys
    ``0/r2/navigate_to_pose/_action/...``); a goal there drives r2 alone, in r2's ``r2/odom`` frame as a ROS user
    of that node names it."""
    port = ros_graph(children, "--robots", "2", "--distro", "jazzy")
    with zenoh.open(client_config(port)) as session:
        for robot in ("r1", "r2"):
            robot_ready(session, f"fleet/{robot}")
        truths = {robot: Truth(session, f"fleet/{robot}/sim/truth") for robot in ("r1", "r2")}
        client = ActionClient(session, "jazzy", "/r2/navigate_to_pose", node="fleet_navigate_client")
        try:
            wait_for(client.server_is_available, timeout=30, interval=0.5, what="r2's action server")
            assert client.keys["send_goal"].startswith("0/r2/navigate_to_pose/_action/send_goal/")
            goal_id, reply = client.send_goal(0.4, 0.0, 0.0, frame="r2/odom")
            assert reply.message["accepted"], reply
            assert client.get_result(goal_id, timeout=60).message["status"] == SUCCEEDED
            wait_for(lambda: len(client.feedback_of(goal_id)) > 5, what="r2's feedback")
            end = truths["r2"].samples[-1][1]
            assert math.dist((end.x, end.y), (0.4, 0.0)) < 0.03
            assert truths["r1"].samples and all(abs(p.x) < 1e-9 and abs(p.v) < 1e-9 for _, p in truths["r1"].samples), "r1 moved"
            assert client.errors == []
        finally:
            client.close()


def test_rviz_2d_goal_pose_and_2d_pose_estimate(graph: zenoh.Session) -> None:
    """RViz's tools as rmw_zenoh publishers: *2D Goal Pose* (``/goal_pose``, a PoseStamped in ``map``) on Jazzy keys
    drives the robot there, reported on the action's feedback and status; *2D Pose Estimate* (``/initialpose``, a
    PoseWithCovarianceStamped) on Humble keys puts the robot there on the map (``map -> odom`` moves)."""
    truth = Truth(graph)
    watcher = clients(graph, ("jazzy",))["jazzy"]
    goal_pose = TopicPublisher(graph, "jazzy", "/goal_pose", "geometry_msgs/msg/PoseStamped", node="rviz2")
    initial_pose = TopicPublisher(graph, "humble", "/initialpose", "geometry_msgs/msg/PoseWithCovarianceStamped", node="rviz2")
    try:
        time.sleep(0.5)  # the tokens and the publishers' declarations reach the router
        target = (0.5, 0.2, 0.4)
        goal_pose.publish(
            {
                "header": stamped_now("map"),
                "pose": {"position": {"x": target[0], "y": target[1]}, "orientation": quaternion_from_yaw(target[2])},
            }
        )
        wait_for(truth.moving, what="the robot driving to RViz's goal")
        wait_for(lambda: watcher.statuses and watcher.statuses[-1][1]["status_list"] and watcher.statuses[-1][1]["status_list"][-1]["status"] == SUCCEEDED,
                 timeout=60, what="RViz's goal SUCCEEDED in the action's status")  # fmt: skip
        end = truth.samples[-1][1]
        assert math.dist((end.x, end.y), target[:2]) < 0.03 and angle(end.yaw, target[2]) < math.radians(3), end
        assert watcher.feedback, "no feedback for RViz's goal on the action's feedback topic"

        here = (5.0, -2.0, 1.0)  # "the robot is here on the map now"
        covariance = [0.0] * 36
        initial_pose.publish(
            {
                "header": stamped_now("map"),
                "pose": {
                    "pose": {"position": {"x": here[0], "y": here[1]}, "orientation": quaternion_from_yaw(here[2])},
                    "covariance": covariance,
                },
            }
        )

        def on_map_now() -> tuple[float, float, float] | None:
            odom = [json.loads(r.ok.payload.to_bytes()) for r in graph.get("robot/pose", timeout=2) if r.ok is not None]
            placed = [json.loads(r.ok.payload.to_bytes()) for r in graph.get("robot/nav/map_pose", timeout=2) if r.ok is not None]
            if not odom or not placed:
                return None
            p, m = odom[0], placed[0]
            c, s = math.cos(m["yaw"]), math.sin(m["yaw"])
            return (m["x"] + c * p["x"] - s * p["y"], m["y"] + s * p["x"] + c * p["y"], m["yaw"] + p["yaw"])

        placed = wait_for(lambda: (q := on_map_now()) and math.dist(q[:2], here[:2]) < 0.01 and q, what="the robot placed where RViz said")
        assert angle(placed[2], here[2]) < math.radians(1), placed
    finally:
        goal_pose.close()
        initial_pose.close()
        watcher.close()


def test_kilted_and_rolling_keys_with_their_own_navigate_to_pose(children: list[Child]) -> None:
    """Kilted's hashes are Jazzy's; Rolling's feedback carries ``position_tracking_error`` and
    ``heading_tracking_error`` (another layout, another hash): each distro's client reads its node's feedback.
    Kilted's and Rolling's send_goal, get_result, cancel_goal and status have one key (the same definitions): one
    server answers there, once (two would give two answers to one goal, the second "goal id taken", in any order)."""
    port = ros_graph(children, "--distro", "kilted,rolling")
    with zenoh.open(client_config(port)) as session:
        robot_ready(session)
        made = {distro: ActionClient(session, distro, node=f"{distro}_navigate_client") for distro in ("kilted", "rolling")}
        try:
            for distro, client in made.items():
                wait_for(client.server_is_available, timeout=30, interval=0.5, what=f"the {distro} action server")
            for distro, (x, y, yaw) in {"kilted": (0.4, 0.1, 0.5), "rolling": (0.0, 0.0, 0.0)}.items():
                client = made[distro]
                goal_id, reply = client.send_goal(x, y, yaw)
                assert reply.message["accepted"], reply
                assert client.get_result(goal_id, timeout=60).message["status"] == SUCCEEDED
                for name, other in made.items():
                    times = [t for t, _ in other.feedback_of(goal_id)]
                    print(f"{distro} goal: its feedback on {name}'s key: {len(times)} at {rate(times):.1f} Hz")
                    assert rate(times) >= 5.0
            last = made["rolling"].feedback[-1][1]["feedback"]
            assert {"position_tracking_error", "heading_tracking_error"} <= set(last)
            assert "position_tracking_error" not in made["kilted"].feedback[-1][1]["feedback"]
            for client in made.values():
                assert client.errors == []
        finally:
            for client in made.values():
                client.close()


def test_a_held_get_result_ends_when_the_navigation_dies(children: list[Child]) -> None:
    """rmw_zenoh's client waits for get_result without a timeout: when the navigation process dies mid-goal the held
    call must still end (ABORTED, or UNKNOWN once nobody knows the goal) within 10 s, or ``ros2 action send_goal``
    waits for ever on a robot that has stopped."""
    from integration.test_open_rmf import start_site

    port = start_site(children)
    (nav,) = [c for c in children if c.args[2:3] == ["nav"]]
    with zenoh.open(client_config(port)) as session:
        robot_ready(session)
        truth = Truth(session)
        client = clients(session, ("jazzy",))["jazzy"]
        try:
            goal_id, reply = client.send_goal(3.0, 0.0, 0.0)
            assert reply.message["accepted"]
            pending = client.get_result_async(goal_id, timeout=30)
            wait_for(truth.moving, what="the robot driving")
            killed = time.monotonic()
            nav.proc.kill()
            nav.proc.wait(10)
            pending["thread"].join(15)
            assert "reply" in pending, f"the held get_result did not end within 15 s of the navigation's death: {pending.get('error')}"
            status = pending["reply"].message["status"]
            print(f"navigation killed: the held get_result ended {time.monotonic() - killed:.1f} s later with {STATUS[status]}")
            assert status in (6, 0), STATUS[status]
        finally:
            client.close()


def test_an_e_stop_during_a_goal_aborts_it_with_its_reason_in_the_result(graph: zenoh.Session) -> None:
    """Jazzy's result carries why: ABORTED, ``error_code`` 9000 (UNKNOWN: NavigateToPose has no e-stop code) and the
    navigation's sentence in ``error_msg``; nothing moves after the release."""
    truth = Truth(graph)
    client = clients(graph, ("jazzy",))["jazzy"]
    try:
        goal_id, reply = client.send_goal(2.5, 0.0, 0.0)
        assert reply.message["accepted"]
        pending = client.get_result_async(goal_id, timeout=30)
        wait_for(truth.moving, what="the robot driving")
        since = time.monotonic()
        graph.put("robot/estop", json.dumps({"engaged": True}))
        stopped = wait_for(lambda: truth.stopped_after(since), timeout=5, what="the robot stopped by the e-stop")
        pending["thread"].join(15)
        assert "reply" in pending, pending.get("error")
        result = pending["reply"].message
        print(f"e-stop during a ROS goal: stopped after {1000 * stopped:.0f} ms; {STATUS[result['status']]}: {result['result']}")
        assert (
            result["status"] == 6 and result["result"]["error_code"] == 9000 and re.search(r"e-?stop", result["result"]["error_msg"], re.I)
        )
        assert client.status_of(goal_id)[-1:] == [6] or wait_for(lambda: client.status_of(goal_id)[-1:] == [6], timeout=5)
        graph.put("robot/estop/release", json.dumps({"engaged": False}))
        time.sleep(2.0)
        released = [p for t, p in truth.samples if t > since + stopped]
        assert released and all(abs(p.v) < 1e-9 and abs(p.w) < 1e-9 for p in released), "the robot moved after the release"
    finally:
        client.close()
