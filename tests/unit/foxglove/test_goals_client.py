"""Goals from Foxglove's 3D panel, end to end: a WebSocket client that speaks as Studio does (``foxglove.websocket.v1``,
the panel's own advertisements, JSON) against ``blackmetal foxglove``, and a stand-in for the navigation service: Zenoh
queryables on ``robot/nav/goal`` and ``robot/nav/set_pose`` that record what reached them and answer as the service does.
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh
from helpers import Child, free_port, wait_for, zenoh_connect_args

from blackmetal.foxglove.front import LEGACY_SUBPROTOCOL
from blackmetal.schemas import (
    GoalState,
    Keys,
    MapPose,
    NavCancel,
    NavCancelReply,
    NavFeedback,
    NavGoal,
    NavGoalReply,
    PlanarPose,
    Pose,
    SetPose,
    decode,
    encode,
)
from unit.foxglove.test_fleet import FleetClient
from unit.foxglove.test_live import protobuf_class

KEYS = Keys("robot")
GOAL_ID = "0123456789abcdef" * 2
#: What the 3D panel advertises as it opens (ROS 1's schema names), and the goal topic the shipped layout sets.
PANEL = {
    1: ("/move_base_simple/goal", "geometry_msgs/PoseStamped"),
    2: ("/clicked_point", "geometry_msgs/PointStamped"),
    3: ("/initialpose", "geometry_msgs/PoseWithCovarianceStamped"),
    4: ("/goal_pose", "geometry_msgs/PoseStamped"),
}


def stamped(x: float, y: float, yaw: float, frame: str, covariance: bool = False) -> bytes:
    """What the panel's publish tools send: a header (ROS 1's stamp) and a pose (with a covariance for an estimate)."""
    pose = {"position": {"x": x, "y": y, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}}
    header = {"stamp": {"sec": 1764000000, "nsec": 250000000}, "frame_id": frame}
    return json.dumps({"header": header, "pose": {"covariance": [0.0] * 36, "pose": pose} if covariance else pose}).encode()


class Navigation:
    """The stand-in: answers goals (one beyond x = 100 is rejected, as a geofence would) and set-poses; keeps what came."""

    def __init__(self, session: zenoh.Session) -> None:
        self.goals: list[NavGoal] = []
        self.placed: list[SetPose] = []
        self._lock = threading.Lock()
        self._entities = [
            session.declare_queryable(KEYS.nav_goal, self._on_goal),
            session.declare_queryable(KEYS.nav_set_pose, self._on_set_pose),
            session.declare_queryable(KEYS.nav_cancel, self._on_cancel),
            # the odometry's pose, for a goal in the robot's own frame: at (1, 1), facing +y
            session.declare_queryable(
                KEYS.pose, lambda query: query.reply(KEYS.pose, encode(Pose(stamp=1.0, x=1.0, y=1.0, yaw=math.pi / 2)))
            ),
        ]

    def _on_goal(self, query: zenoh.Query) -> None:
        goal = decode(NavGoal, query.payload.to_bytes() if query.payload is not None else b"")
        with self._lock:
            self.goals.append(goal)
        far = goal.x > 100
        reply = NavGoalReply(accepted=not far, goal_id=None if far else GOAL_ID, reason="the goal is outside the geofence" if far else "")
        query.reply(KEYS.nav_goal, encode(reply))

    def _on_cancel(self, query: zenoh.Query) -> None:
        decode(NavCancel, query.payload.to_bytes() if query.payload is not None else b"")
        query.reply(KEYS.nav_cancel, encode(NavCancelReply(canceled=[GOAL_ID])))

    def _on_set_pose(self, query: zenoh.Query) -> None:
        placed = decode(SetPose, query.payload.to_bytes() if query.payload is not None else b"")
        with self._lock:
            self.placed.append(placed)
        query.reply(KEYS.nav_set_pose, encode(MapPose(stamp=1.0, x=placed.x, y=placed.y, yaw=placed.yaw, by="/initialpose")))

    def close(self) -> None:
        for entity in self._entities:
            entity.undeclare()


@pytest.fixture(scope="module")
def view() -> Iterator[tuple[str, zenoh.Session]]:
    """``blackmetal foxglove`` on a Zenoh session of the test's own (listening on loopback, nothing else on it)."""
    zport = free_port()
    conf = zenoh.Config()
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{zport}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    child = Child(["-m", "blackmetal", "foxglove", "--port", "0", *zenoh_connect_args(zport)])
    try:
        yield child.ready()["url"], session
    finally:
        child.stop()
        session.close()


@pytest.mark.integration
def test_a_goal_from_the_3d_panel_reaches_nav_goal_and_the_answer_is_shown(view: tuple[str, zenoh.Session]) -> None:
    url, session = view
    navigation = Navigation(session)
    client = FleetClient(url, [LEGACY_SUBPROTOCOL])  # as Studio 1.48 connects
    try:
        info = client.server_info
        assert info is not None and info["metadata"]["ROS_DISTRO"] == "humble", "a ROS profile: the panel's publish tools show"
        client.wait(lambda: "/log" in client.channels(), "the /log channel")
        log_class = protobuf_class(client.channels()["/log"])
        client.subscribe(1, "/log")
        for channel, (topic, schema) in PANEL.items():
            client.advertise(channel, topic, schema)

        client.publish(4, stamped(1.25, -0.5, math.pi / 2, "map"))  # "Publish pose", the display frame map
        wait_for(lambda: navigation.goals, what="the goal at the navigation service")
        (goal,) = navigation.goals
        assert (goal.x, goal.y, goal.frame) == (1.25, -0.5, "map") and goal.yaw == pytest.approx(math.pi / 2)

        def shown(words: str) -> list[str]:
            lines = [log_class.FromString(m).message for m in client.messages[1]]
            return [line for line in lines if words in line]

        client.wait(lambda: shown(f"accepted as {GOAL_ID}"), "the acceptance in /log")
        client.publish(1, stamped(500.0, 0.0, 0.0, "odom"))  # RViz's topic, the odometry frame, out of the fence
        client.wait(lambda: shown("outside the geofence"), "the rejection in /log")
        client.wait(lambda: any("outside the geofence" in s["message"] and s["level"] == 1 for s in client.statuses()), "its status")
        assert navigation.goals[-1].frame == "odom"

        client.publish(4, stamped(2.0, 0.0, 0.0, "base_link"))  # the display frame of a panel that follows the robot
        wait_for(lambda: len(navigation.goals) == 3, what="the goal placed from the robot's pose")
        ahead = navigation.goals[-1]
        assert ahead.frame == "odom" and (ahead.x, ahead.y) == pytest.approx((1.0, 3.0)) and ahead.yaw == pytest.approx(math.pi / 2)

        client.publish(3, stamped(2.0, 3.0, -math.pi / 2, "map", covariance=True))  # "Publish pose estimate"
        wait_for(lambda: navigation.placed, what="the set-pose")
        assert (navigation.placed[0].x, navigation.placed[0].y) == (2.0, 3.0) and navigation.placed[0].yaw == pytest.approx(-math.pi / 2)
        client.wait(lambda: shown("map -> odom now (2.00, 3.00)"), "the set-pose's answer")
        client.publish(2, b'{"header": {"frame_id": "map"}, "point": {"x": 0.5, "y": 0.25, "z": 0.0}}')
        client.wait(lambda: shown("clicked point (0.50, 0.25, 0.00) in map"), "the clicked point")
        assert len(navigation.goals) == 3, "a point moves nothing"
        response, failure = client.call("cancel_goal", b"{}")  # the layout's cancel button
        assert failure is None and response == {"success": True, "message": f"canceled {GOAL_ID}"}
        assert not [s for s in client.statuses() if s["level"] == 2], "no error: the panel's topics are all taken"
    finally:
        client.close()
        navigation.close()


@pytest.mark.integration
def test_nav_feedback_and_the_map_frame_reach_the_client(view: tuple[str, zenoh.Session]) -> None:
    url, session = view
    map_pose = encode(MapPose(stamp=5.0, x=10.0, y=20.0, yaw=0.0))
    queryable = session.declare_queryable(KEYS.nav_map_pose, lambda query: query.reply(KEYS.nav_map_pose, map_pose))
    client = FleetClient(url)
    try:
        client.wait(lambda: {"/nav/feedback", "/nav/goal", "/tf"} <= set(client.channels()), "the navigation channels")
        channels = client.channels()
        assert channels["/nav/feedback"]["schemaName"] == "NavFeedback"
        assert json.loads(channels["/nav/feedback"]["schema"])["type"] == "object", "Studio's parser wants an object at the top"
        tf_class, goal_class = protobuf_class(channels["/tf"]), protobuf_class(channels["/nav/goal"])
        for subscription, topic in enumerate(("/tf", "/nav/feedback", "/nav/goal"), start=1):
            client.subscribe(subscription, topic)

        def map_to_odom() -> bool:
            return any(t.parent_frame_id == "map" and t.child_frame_id == "odom" for t in map(tf_class.FromString, client.messages[1]))

        client.wait(map_to_odom, "map -> odom, asked for as /tf was watched")
        goal = PlanarPose(1.0, 2.0, 0.5, "map")
        feedback = NavFeedback(
            stamp=6.0, goal_id=GOAL_ID, state=GoalState.EXECUTING, pose=goal, goal=goal, distance_remaining=1.5, eta=2.0, elapsed=0.5
        )

        def arrived() -> bool:
            session.put(KEYS.nav_feedback, encode(feedback))
            client.pump(0.1)
            return bool(client.messages[2] and client.messages[3])

        client.wait(arrived, "the feedback and the goal")
        assert json.loads(client.messages[2][-1])["distance_remaining"] == 1.5
        shown = goal_class.FromString(client.messages[3][-1])
        assert shown.frame_id == "map" and (shown.pose.position.x, shown.pose.position.y) == (1.0, 2.0)
    finally:
        client.close()
        queryable.undeclare()


@pytest.mark.integration
def test_a_fleets_goals_go_to_the_robot_their_topic_or_frame_names(children: list[Child], tmp_path: Path) -> None:
    """``foxglove --fleet``: /r2/goal_pose to r2's nav/goal, the bare /goal_pose by its frame, a bare one in map refused."""
    zport = free_port()
    conf = zenoh.Config()
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{zport}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    fleet = tmp_path / "fleet.toml"
    fleet.write_text("".join(f'[[robot]]\nid = "{rid}"\ncontrol_port = {n}\nlog_port = {n + 1}\n' for n, rid in ((1, "r1"), (3, "r2"))))
    asked: dict[str, list[NavGoal]] = {"r1": [], "r2": []}

    def stand_in(rid: str) -> Callable[[zenoh.Query], None]:
        def answer(query: zenoh.Query) -> None:
            asked[rid].append(decode(NavGoal, query.payload.to_bytes() if query.payload is not None else b""))
            query.reply(str(query.key_expr), encode(NavGoalReply(accepted=True, goal_id=GOAL_ID)))

        return answer

    with zenoh.open(conf) as session:
        queryables = [session.declare_queryable(f"fleet/{rid}/nav/goal", stand_in(rid)) for rid in asked]
        view = Child(["-m", "blackmetal", "foxglove", "--fleet", str(fleet), "--port", "0", *zenoh_connect_args(zport)])
        children.append(view)
        client = FleetClient(view.ready()["url"], [LEGACY_SUBPROTOCOL])
        try:
            client.wait(lambda: {"/r1/log", "/r2/log", "/fleet/log"} <= set(client.channels()), "the logs")
            client.subscribe(1, "/r2/log")
            client.advertise(1, "/r2/goal_pose", "geometry_msgs/PoseStamped")
            client.advertise(2, "/goal_pose", "geometry_msgs/PoseStamped")  # the 3D panel's default, naming no robot
            client.publish(1, stamped(1.0, 2.0, 0.0, "map"))
            client.publish(2, stamped(3.0, 4.0, 0.0, "r1/odom"))
            client.publish(2, stamped(5.0, 6.0, 0.0, "map"))
            wait_for(lambda: asked["r1"] and asked["r2"], what="a goal at each robot's stand-in")
            assert [(g.x, g.y, g.frame) for g in asked["r2"]] == [(1.0, 2.0, "map")]
            assert [(g.x, g.y, g.frame) for g in asked["r1"]] == [(3.0, 4.0, "odom")]
            client.wait(lambda: any("names none of r1, r2" in s["message"] for s in client.statuses()), "the refusal of a map goal")
            log_class = protobuf_class(client.channels()["/r2/log"])
            client.wait(lambda: any(GOAL_ID in log_class.FromString(m).message for m in client.messages[1]), "r2's answer on /r2/log")
        finally:
            client.close()
            for queryable in queryables:
                queryable.undeclare()
