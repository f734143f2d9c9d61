"""The live Foxglove view, seen by a WebSocket client that speaks Foxglove's protocol as the app does."""

from __future__ import annotations

import base64
import itertools
import json
import math
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from helpers import Child, client_config, free_port, start_robot, zenoh_connect_args
from mcap.reader import make_reader
from websockets.sync.client import connect

from blackmetal.schemas import Pose, decode

#: The subprotocols Foxglove's app offers.
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
EXPECTED = {
    "/pose": "foxglove.PoseInFrame",
    "/tf": "foxglove.FrameTransform",
    "/path": "foxglove.PosesInFrame",
    "/truth/pose": "foxglove.PoseInFrame",
    "/truth/path": "foxglove.PosesInFrame",
    "/odometry": "Pose",
    "/wheels": "WheelSpeeds",
    "/status": "RobotStatus",
    "/health": "GatewayHealth",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    "/errors": "ErrorReport",
    "/log": "foxglove.Log",
    "/joint_states": "sensor_msgs/msg/JointState",
    "/robot_description": "std_msgs/msg/String",
    "/nav/feedback": "NavFeedback",
    "/nav/goal": "foxglove.PoseInFrame",
    "/nav/plan": "foxglove.PosesInFrame",
}


def readable(message: Any) -> Any:
    """One of the SDK's Foxglove messages as protobuf, its fields readable (the SDK's own objects only encode)."""
    schema = message.get_schema()
    channel = {"schema": base64.b64encode(bytes(schema.data)).decode(), "schemaName": schema.name}
    return protobuf_class(channel).FromString(message.encode())


def protobuf_class(channel: dict[str, Any]) -> Any:
    """The message class of an advertised protobuf channel, built from its FileDescriptorSet."""
    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for file in files.file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


@pytest.mark.integration
def test_foxglove_client_sees_the_robot_drive(children: list[Child], tmp_path: Path) -> None:
    zport = free_port()
    start_robot(children, zport)
    mcap_path = tmp_path / "view.mcap"
    view = Child(["-m", "blackmetal", "foxglove", "--port", "0", "--mcap", str(mcap_path), *zenoh_connect_args(zport)])
    children.append(view)
    url = view.ready()["url"]
    with connect(url, subprotocols=SUBPROTOCOLS, open_timeout=20) as ws, zenoh.open(client_config(zport)) as session:  # type: ignore[arg-type]
        assert ws.subprotocol in SUBPROTOCOLS
        channels: dict[str, dict[str, Any]] = {}
        server_info = None
        deadline = time.monotonic() + 20
        while (server_info is None or set(channels) < set(EXPECTED)) and time.monotonic() < deadline:
            message = ws.recv(timeout=20)
            if isinstance(message, str):
                op = json.loads(message)
                if op["op"] == "serverInfo":
                    server_info = op
                elif op["op"] == "advertise":
                    channels.update({c["topic"]: c for c in op["channels"]})
        assert server_info is not None and server_info["name"] == "blackmetal"
        assert {topic: channels[topic]["schemaName"] for topic in EXPECTED} == EXPECTED
        assert channels["/odometry"]["encoding"] == "json" and channels["/odometry"]["schemaEncoding"] == "jsonschema"
        pose_class = protobuf_class(channels["/pose"])
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channels["/pose"]["id"]}]}))

        xs: list[float] = []
        frames: set[str] = set()
        end = time.monotonic() + 3.0
        while time.monotonic() < end:  # drive forward at 10 Hz and read what the view sends
            session.put("robot/cmd_vel", json.dumps({"linear": {"x": 0.3}}))
            stop_reading = time.monotonic() + 0.1
            while time.monotonic() < stop_reading:
                try:
                    message = ws.recv(timeout=0.05)
                except TimeoutError:
                    break
                if isinstance(message, bytes) and message[0] == 0x01:
                    (subscription,) = struct.unpack_from("<I", message, 1)
                    assert subscription == 7
                    pose = pose_class.FromString(message[13:])
                    xs.append(pose.pose.position.x)
                    frames.add(pose.frame_id)
        replies = [r for r in session.get("robot/pose", timeout=5) if r.ok is not None]
        odometry_x = decode(Pose, replies[0].ok.payload.to_bytes()).x
        assert frames == {"odom"}
        assert len(xs) > 50 and xs[-1] - xs[0] > 0.3, (xs[:3], xs[-3:])
        assert all(b >= a - 1e-9 for a, b in itertools.pairwise(xs)), "x follows the forward drive"
        assert abs(xs[-1] - odometry_x) < 0.1
    assert view.stop() == 0
    with open(mcap_path, "rb") as handle:
        topics = {channel.topic for _, channel, _ in make_reader(handle).iter_messages()}
    assert {"/pose", "/tf", "/path", "/odometry", "/wheels", "/joint_states", "/robot_description"} <= topics, (
        "an MCAP file takes every channel"
    )


def panels(node: Any) -> Iterator[dict[str, Any]]:
    """Every panel of a layout (Foxglove's layout format: splits, tabs, stacks of panels)."""
    if isinstance(node, dict):
        if node.get("type") == "panel":
            yield node
        for value in node.values():
            yield from panels(value)
    elif isinstance(node, list):
        for item in node:
            yield from panels(item)


def panel_topics(kind: str, config: dict[str, Any]) -> list[str]:
    """The topics a Plot, Log, DiagnosticsSummary or RawMessages panel shows (none for another panel)."""
    if kind == "Plot":
        return [path["value"].split(".")[0] for path in config["paths"]]
    if kind in ("Log", "DiagnosticsSummary"):
        return [config["topicToRender"]]
    return [config["topicPath"].split(".")[0]] if kind == "RawMessages" else []


def test_the_shipped_layout_uses_the_views_topics_controls_and_services() -> None:
    from blackmetal.foxglove.naming import NavTopic

    layout = json.loads((Path(__file__).parents[3] / "deploy" / "foxglove" / "blackmetal.layout.json").read_text())
    shown: set[str] = set()
    published: dict[str, list[dict[str, Any]]] = {}
    called: dict[str, dict[str, Any]] = {}
    kinds: set[str] = set()
    for panel in panels(layout):
        kind, config = panel["panelType"], panel["config"]
        kinds.add(kind)
        if kind == "ThreeDee":
            shown.update(config["topics"])
            assert config["followTf"] == "base_link"
            (urdf,) = config["layers"].values()  # the robot model, from the view's URDF topic (links unprefixed)
            assert (urdf["layerId"], urdf["sourceType"], urdf["topic"], urdf["framePrefix"]) == (
                "foxglove.Urdf",
                "topic",
                "/robot_description",
                "",
            )
            shown.add(urdf["topic"])
            # its publish tool sends goals (Foxglove's config names, as in its PublishSettings), each to a topic the view takes
            tool = config["publish"]
            assert (tool["type"], tool["poseTopic"], tool["poseEstimateTopic"], tool["pointTopic"]) == (
                "pose",
                "/goal_pose",
                "/initialpose",
                "/clicked_point",
            )
            assert {tool["poseTopic"], tool["poseEstimateTopic"], tool["pointTopic"]} <= {t.value for t in NavTopic}
            assert config["topics"]["/nav/goal"]["visible"] and config["topics"]["/nav/plan"]["visible"], "the goal and the way there"
        else:
            shown.update(panel_topics(kind, config))
        if kind == "Teleop":
            published.setdefault(config["topic"], []).append(config)
            assert config["publishRate"] >= 5, "the gateway's source timeout is 0.5 s: the panel must publish faster than that"
        elif kind == "Publish":
            published.setdefault(config["topicName"], []).append(config)
        elif kind == "ServiceCall":
            called[config["serviceName"]] = json.loads(config["requestPayload"])
    assert shown and shown <= set(EXPECTED), shown - set(EXPECTED)
    assert {"/odometry", "/log", "/path", "/diagnostics", "/robot_description", "/nav/feedback", "/nav/goal"} <= shown
    assert {"Teleop", "Publish", "DiagnosticsSummary", "Parameters"} <= kinds
    assert set(published) == {"/cmd_vel", "/estop"}
    (stop_button,) = published["/estop"]
    assert stop_button["datatype"] == "std_msgs/msg/Bool" and json.loads(stop_button["value"]) == {"data": True}
    assert set(called) <= {"set_estop", "reset_odometry", "cancel_goal"} and called.get("set_estop") == {"data": False}
    assert called.get("cancel_goal") == {}, "the goals' stop button"


def test_each_key_feeds_its_channels_and_a_payload_that_does_not_decode_is_skipped() -> None:
    from blackmetal.foxglove.live import LiveView
    from blackmetal.schemas import Keys, encode
    from unit.foxglove.test_fleet_view import Logged

    logs: dict[str, list[Any]] = {}
    keys = Keys("robot")
    view = LiveView(keys, "r1", channel=lambda topic, kind, schema: Logged(topic, kind, schema, logs))
    assert {topic.removeprefix("/r1") for topic in logs} == set(EXPECTED) | {"/tf"}
    assert view.feeds() == {
        keys.pose: {"/r1/pose", "/r1/tf", "/r1/path", "/r1/odometry"},
        keys.sim_truth: {"/r1/truth/pose", "/r1/truth/path"},
        keys.impulses: {"/r1/wheels", "/r1/joint_states", "/r1/tf"},
        keys.status: {"/r1/status"},
        keys.health: {"/r1/health", "/r1/diagnostics"},
        keys.errors: {"/r1/errors", "/r1/log"},
        keys.nav_feedback: {"/r1/nav/feedback", "/r1/nav/goal", "/r1/nav/plan"},
        keys.nav_map_pose: {"/r1/tf"},
    }
    assert set(view.handlers()) == set(view.feeds())
    pose = encode(Pose(stamp=1.0, x=1.0, y=2.0, yaw=0.0))
    view.handlers()[keys.pose](pose)
    assert logs["/r1/odometry"] == [pose] and len(logs["/r1/pose"]) == len(logs["/r1/path"]) == 1
    frames = [(t.parent_frame_id, t.child_frame_id) for t in map(readable, logs["/r1/tf"])]
    # the pose on odom -> base_footprint, the URDF's root, and its fixed joints with it (#40: base_link had two parents)
    assert frames == [("r1/odom", "r1/base_footprint"), ("r1/base_footprint", "r1/base_link"), ("r1/base_link", "r1/caster")]
    view.handlers()[keys.pose](b"not a pose")
    assert len(logs["/r1/odometry"]) == 1, "skipped, never raised"


def test_navigation_shows_its_feedback_the_goal_in_its_frame_and_map_to_odom_on_tf() -> None:
    from blackmetal.foxglove.live import MAP_TF_PERIOD_S, LiveView
    from blackmetal.foxglove.naming import StatusLevel
    from blackmetal.schemas import GoalState, Keys, MapPose, NavFeedback, PlanarPose, encode
    from unit.foxglove.test_fleet_view import Logged

    logs: dict[str, list[Any]] = {}
    keys = Keys("fleet/r2")
    view = LiveView(keys, "r2", channel=lambda topic, kind, schema: Logged(topic, kind, schema, logs))
    handlers = view.handlers()
    handlers[keys.nav_map_pose](encode(MapPose(stamp=10.0, x=3.0, y=-1.0, yaw=math.pi / 2)))
    (placed,) = map(readable, logs["/r2/tf"])
    assert (placed.parent_frame_id, placed.child_frame_id) == ("map", "r2/odom"), "the site map over this robot's odometry"
    assert (placed.translation.x, placed.translation.y) == (3.0, -1.0) and placed.rotation.z == pytest.approx(math.sqrt(0.5))
    for i in range(30):  # 3 s of poses at 10 Hz: map -> odom again once a second, for a client that came late
        handlers[keys.pose](encode(Pose(stamp=10.0 + 0.1 * i, x=0.0, y=0.0, yaw=0.0)))
    sent = [readable(t) for t in logs["/r2/tf"]]
    again = [t for t in sent[1:] if t.parent_frame_id == "map"]
    assert len(again) == 1 + int(2.9 / MAP_TF_PERIOD_S), "with the first pose, then once a second"
    assert {t.child_frame_id for t in sent} == {"r2/odom", "r2/base_footprint", "r2/base_link", "r2/caster"}

    for goal_frame, shown_frame in (("map", "map"), ("odom", "r2/odom")):
        feedback = NavFeedback(
            stamp=11.0,
            goal_id="ab" * 16,
            state=GoalState.EXECUTING,
            pose=PlanarPose(0.0, 0.0, 0.0, goal_frame),
            goal=PlanarPose(2.0, 1.0, math.pi, goal_frame),
            distance_remaining=2.2,
            eta=3.0,
            elapsed=1.0,
        )
        handlers[keys.nav_feedback](encode(feedback))
        assert logs["/r2/nav/feedback"][-1] == encode(feedback), "the service's feedback as it said it"
        goal = readable(logs["/r2/nav/goal"][-1])
        assert goal.frame_id == shown_frame and (goal.pose.position.x, goal.pose.position.y) == (2.0, 1.0)
        assert goal.pose.orientation.z == pytest.approx(1.0)
        plan = readable(logs["/r2/nav/plan"][-1])
        assert plan.frame_id == shown_frame and [(p.position.x, p.position.y) for p in plan.poses] == [(0.0, 0.0), (2.0, 1.0)]
    handlers[keys.nav_feedback](b'{"stamp": 1}')
    handlers[keys.nav_map_pose](b"not a map pose")
    assert len(logs["/r2/nav/feedback"]) == 2, "skipped, never raised"

    view.nav_event(StatusLevel.WARNING, "the navigation service rejected the goal: e-stop")
    line = readable(logs["/r2/log"][-1])
    assert line.name == "nav" and line.message.endswith("e-stop")
