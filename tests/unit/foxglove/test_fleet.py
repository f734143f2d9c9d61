"""``blackmetal foxglove --fleet FILE``: every robot of a fleet in one view, on one port.

Pure: the names (``/r3/cmd_vel``, ``/r3/set_estop``, frames ``r3/odom``), the
fleet summary, and :class:`FleetControls` routing each client message to its
robot's controls alone, on a fake clock. Against real processes: three
simulated robots behind one gateway and one odometry process, and one view;
a WebSocket client (as the app) sees every robot's channels, gets ``/r2/pose``,
drives r3 alone on ``/r3/cmd_vel``, engages r1's e-stop alone with
``/r1/set_estop``, and a bad message for r2 is refused and reported on r2's
errors key only.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import pytest
import zenoh
from helpers import Child, client_config, free_port, wait_for, zenoh_listen_args

from blackmetal.foxglove.controls import Controls, FleetControls
from blackmetal.foxglove.fleet import Wiring, fleet_settings
from blackmetal.foxglove.live import LiveView
from blackmetal.foxglove.naming import (
    COMMAND_SOURCE,
    Control,
    Service,
    StatusLevel,
    control_topic,
    robot_frame,
    robot_namespace,
    service_name,
)
from blackmetal.foxglove.settings import FoxgloveSettings
from blackmetal.foxglove.watch import Watch
from blackmetal.foxglove.zenoh_edge import NO_EDGE
from blackmetal.runtime.fleet import parse_fleet
from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import ConfigError, ErrorReport, EStop, GatewayHealth, Keys, Pose, Twist, decode, encode
from unit.foxglove.test_controls import TWIST_FORWARD, Bench, FoxClient, health
from unit.foxglove.test_fleet_view import Logged
from unit.foxglove.test_live import EXPECTED, panel_topics, panels, protobuf_class

IDS = ("r1", "r2", "r3")


# --------------------------------------------------------------------------- pure: names


def test_fleet_settings_take_each_robots_prefix_and_refuse_what_the_one_server_decides() -> None:
    robots = parse_fleet(
        {"robot": [{"id": "r1", "control_port": 1, "log_port": 2}, {"id": "r2", "control_port": 3, "log_port": 4, "prefix": "lab/b"}]}
    )
    one, two = fleet_settings(FoxgloveSettings(port=0), robots)
    assert (one.prefix, two.prefix, two.port) == ("fleet/r1", "lab/b", 0)

    def refused(entry: dict[str, Any]) -> str:
        with pytest.raises(ConfigError) as info:
            fleet_settings(FoxgloveSettings(), parse_fleet({"robot": [{"control_port": 1, "log_port": 2, **entry}]}))
        return str(info.value)

    assert "port is not a [robot.foxglove] setting" in refused({"id": "a", "foxglove": {"port": 9000}})
    assert "keeps /fleet/ for its own topics" in refused({"id": "fleet"})


# --------------------------------------------------------------------------- pure: the summary


# --------------------------------------------------------------------------- pure: FleetControls, on a fake clock
class FleetBench:
    """Each robot's Bench, and what the fleet refused on its own."""

    def __init__(self) -> None:
        self.benches = {rid: Bench() for rid in IDS}
        self.statuses: list[tuple[int | None, StatusLevel, str]] = []
        self.answers: dict[int, tuple[bytes | None, str | None]] = {}
        self.fleet_errors: list[ErrorReport] = []
        robots = {
            rid: Controls(Keys(f"fleet/{rid}"), b, wallclock=lambda: 1000.0, namespace=robot_namespace(rid), robot=b)
            for rid, b in self.benches.items()
        }
        self.core = FleetControls(robots, self, self.fleet_errors.append, wallclock=lambda: 1000.0)

    def status(self, client: int | None, level: StatusLevel, message: str) -> None:
        self.statuses.append((client, level, message))

    def answer(self, call: int, response: bytes | None, failure: str | None) -> None:
        self.answers[call] = (response, failure)


def test_fleet_controls_send_each_robots_commands_to_its_prefix_alone() -> None:
    fleet = FleetBench()
    core, b = fleet.core, fleet.benches
    core.on_advertise(1, 10, "/r3/cmd_vel", "json", "geometry_msgs/msg/Twist", 0.0)
    core.on_message(1, 10, TWIST_FORWARD, 0.1)
    assert b["r3"].commands == [("fleet/r3/cmd_vel/foxglove", encode(decode(Twist, TWIST_FORWARD)))]
    assert not b["r1"].commands and not b["r2"].commands
    core.on_service_call(1, 1, "/r1/set_estop", b'{"data": true}', 0.2)
    assert [decode(EStop, p).engaged for k, p in b["r1"].commands if k == "fleet/r1/estop"] == [True] and b["r1"].health_asks == 1
    core.robots["r2"].on_health(health(True), 0.3)  # r2's e-stop does not answer r1's call
    assert not b["r1"].answers
    core.robots["r1"].on_health(health(True), 0.3)
    assert b["r1"].answers[1][1] is None
    core.on_service_call(2, 1, "/r2/reset_odometry", b"{}", 0.4)
    assert [call for call, _ in b["r2"].resets] == [2]
    core.robots["r2"].on_reset_reply(2, None, None, 0.5)
    assert "no odometry answered on fleet/r2/odometry/reset" in str(b["r2"].answers[2][1])
    core.on_client_gone(1, 0.6)  # the driver left: one zero to r3, nothing to the others
    assert b["r3"].commands[-1] == ("fleet/r3/cmd_vel/foxglove", encode(Twist())) and not b["r2"].commands


def test_fleet_goals_go_to_the_robot_their_topic_or_frame_names() -> None:
    fleet = FleetBench()
    core, b = fleet.core, fleet.benches
    goal = b'{"header": {"frame_id": "FRAME"}, "pose": {"position": {"x": 1.0, "y": 2.0}}}'
    core.on_advertise(3, 1, "/r3/goal_pose", "json", "geometry_msgs/PoseStamped", 0.0)
    core.on_advertise(3, 2, "/goal_pose", "json", "geometry_msgs/PoseStamped", 0.0)  # the 3D panel's own, with no robot's name
    core.on_advertise(3, 3, "/clicked_point", "json", "geometry_msgs/PointStamped", 0.0)
    assert not fleet.statuses and not fleet.fleet_errors and not any(bench.statuses for bench in b.values())
    core.on_message(3, 1, goal.replace(b"FRAME", b"map"), 0.1)
    core.on_message(3, 2, goal.replace(b"FRAME", b"r2/odom"), 0.1)
    assert [(key, json.loads(payload)["frame"]) for key, _, payload in b["r3"].nav] == [("fleet/r3/nav/goal", "map")]
    assert [(key, json.loads(payload)["frame"]) for key, _, payload in b["r2"].nav] == [("fleet/r2/nav/goal", "odom")]
    core.on_message(3, 2, goal.replace(b"FRAME", b"map"), 0.2)  # which robot's map goal? none said
    core.on_message(3, 2, b"{oops", 0.2)
    assert len(fleet.fleet_errors) == 2 and "publish on /<id>/goal_pose or set the 3D panel's frame to <id>/odom" in fleet.statuses[0][2]
    core.on_message(3, 1, goal.replace(b"FRAME", b"r1/odom"), 0.3)  # r1's frame on r3's topic
    assert len(b["r3"].nav) == 1 and "not this robot's map or odometry frame" in b["r3"].errors[-1].reason and not b["r1"].nav
    core.on_client_gone(3, 0.4)
    core.on_message(3, 2, goal.replace(b"FRAME", b"r2/odom"), 0.5)
    assert len(b["r2"].nav) == 1, "its channels went with it"


def test_fleet_controls_refuse_a_robots_bad_input_on_its_key_and_what_names_no_robot_on_the_fleets() -> None:
    fleet = FleetBench()
    core, b = fleet.core, fleet.benches
    core.on_advertise(2, 1, "/r2/cmd_vel", "json", "geometry_msgs/msg/Twist", 0.0)
    core.on_message(2, 1, b"{bad json", 0.1)
    assert not b["r2"].commands and b["r2"].errors and b["r2"].statuses[0][0] == 2 and "/r2/cmd_vel" in b["r2"].statuses[0][2]
    core.on_advertise(2, 2, "/r2/teleport", "json", "x", 0.0)
    assert "/r2/cmd_vel (geometry_msgs/msg/Twist)" in b["r2"].errors[-1].reason
    assert not b["r1"].errors and not b["r3"].errors and not fleet.fleet_errors
    core.on_advertise(2, 3, "/cmd_vel", "json", "geometry_msgs/msg/Twist", 0.0)  # the single-robot topic: names no robot
    core.on_message(2, 3, TWIST_FORWARD, 0.2)
    core.on_message(2, 99, b"{}", 0.2)
    core.on_service_call(5, 2, "set_estop", b'{"data": true}', 0.3)
    assert all(not bench.commands for bench in b.values())
    assert "/<id>/cmd_vel" in fleet.statuses[0][2] and "r1, r2, r3" in fleet.statuses[0][2]
    assert "unknown service 'set_estop'" in str(fleet.answers[5][1])
    assert {e.key for e in fleet.fleet_errors} == {"foxglove:/cmd_vel", "foxglove:channel 99", "foxglove:set_estop"}
    assert not b["r1"].errors and not b["r3"].errors


def test_the_shipped_fleet_layout_uses_the_fleet_views_topics_controls_and_services() -> None:
    layout = json.loads((Path(__file__).parents[3] / "deploy" / "foxglove" / "blackmetal-fleet.layout.json").read_text())
    topics = {f"{robot_namespace(rid)}{topic}" for rid in IDS for topic in EXPECTED if topic != "/tf"} | {
        "/tf",
        "/fleet/summary",
        "/fleet/log",
    }
    shown: set[str] = set()
    published: dict[str, dict[str, Any]] = {}
    called: dict[str, dict[str, Any]] = {}
    for panel in panels(layout):
        kind, config = panel["panelType"], panel["config"]
        if kind == "ThreeDee":
            shown.update(config["topics"])
            rid = config["followTf"].split("/")[0]
            assert (config["fixedFrame"], config["followTf"]) == (robot_frame(rid, "odom"), robot_frame(rid, "base_link"))
            assert all(topic.startswith(f"/{rid}/") for topic in config["topics"])
            tool = config["publish"]  # its robot's goals: /r2/goal_pose, taken by r2's controls
            assert (tool["type"], tool["poseTopic"], tool["poseEstimateTopic"], tool["pointTopic"]) == (
                "pose",
                f"/{rid}/goal_pose",
                f"/{rid}/initialpose",
                f"/{rid}/clicked_point",
            )
            (urdf,) = config["layers"].values()  # its robot's model: the URDF's links are r2/... already
            assert (urdf["layerId"], urdf["sourceType"], urdf["topic"], urdf["framePrefix"]) == (
                "foxglove.Urdf",
                "topic",
                f"/{rid}/robot_description",
                "",
            )
            shown.add(urdf["topic"])
        else:
            shown.update(panel_topics(kind, config))
        if kind in ("Teleop", "Publish"):
            published[config.get("topic") or config["topicName"]] = config
        elif kind == "ServiceCall":
            called[config["serviceName"]] = json.loads(config["requestPayload"])
    assert shown <= topics, shown - topics
    assert {f"/{rid}/nav/feedback" for rid in IDS} | {f"/{rid}/nav/goal" for rid in IDS} <= shown
    assert "/fleet/summary" in shown and {f"/{rid}/diagnostics" for rid in IDS} | {f"/{rid}/robot_description" for rid in IDS} <= shown
    assert set(published) == {control_topic(robot_namespace(rid), c) for rid in IDS for c in Control}
    assert called == {service_name(robot_namespace(rid), Service.SET_ESTOP): {"data": False} for rid in IDS} | {
        service_name(robot_namespace(rid), Service.CANCEL_GOAL): {} for rid in IDS
    }


# How the view's parts meet: the wiring takes each edge's answers and reaches every robot's edge (fakes, no I/O).


class FakeHost:
    """The host's side the wiring uses: its clock, the timer's poke, its parameters (itself), the clients."""

    def __init__(self) -> None:
        self.pokes = 0
        self.replies: list[tuple[str, tuple[int, bytes | None, bytes | None]]] = []
        self.tables: list[tuple[str, bytes]] = []
        self.answers: dict[int, tuple[bytes | None, str | None]] = {}

    def clock(self) -> float:
        return 5.0

    def poke(self) -> None:
        self.pokes += 1

    @property
    def params(self) -> FakeHost:
        return self

    def on_set_reply(self, robot_id: str, call: int, ok: bytes | None, err: bytes | None, now: float) -> None:
        self.replies.append((robot_id, (call, ok, err)))

    def on_table(self, robot_id: str, payload: bytes, now: float) -> None:
        self.tables.append((robot_id, payload))

    def answer(self, call: int, response: bytes | None, failure: str | None) -> None:
        self.answers[call] = (response, failure)

    def status(self, *args: Any) -> None: ...


class FakeEdge:
    """A robot's edge that keeps what it was asked."""

    declared: frozenset[str] = frozenset()

    def __init__(self) -> None:
        self.wanted: set[str] | None = None
        self.asks = 0
        self.sets: list[tuple[int, bytes]] = []
        self.errors: list[ErrorReport] = []
        self.peeking: bool | None = None

    def want(self, keys: set[str]) -> None:
        self.wanted = keys

    def ask_params(self) -> None:
        self.asks += 1

    def set_params(self, call: int, payload: bytes) -> None:
        self.sets.append((call, payload))

    def error(self, message: ErrorReport) -> None:
        self.errors.append(message)

    def ask_health(self) -> None: ...

    def peek(self, on: bool) -> None:
        self.peeking = on

    def latest_pose(self) -> bytes:
        return b"pose"


def wiring(host: FakeHost, *robot_ids: str, reporter: ErrorReporter | None = None) -> Wiring:
    views, controls = {}, {}
    logs: dict[str, list[Any]] = {}
    for robot_id in robot_ids:
        keys = Keys(f"fleet/{robot_id}" if robot_id else "robot")
        views[robot_id] = LiveView(keys, channel=lambda topic, kind, schema: Logged(topic, kind, schema, logs))
        controls[robot_id] = Controls(keys, host, wallclock=lambda: 1000.0)  # type: ignore[arg-type]
    return Wiring(host, views, controls, Watch(views[robot_ids[0]].feeds()), fleet_reporter=reporter)  # type: ignore[arg-type]


def test_a_robot_is_reached_only_through_the_edge_plugged_in() -> None:
    host = FakeHost()
    one = wiring(host, "")
    assert one.edges[""] is NO_EDGE and one.controls[""].robot is NO_EDGE
    edge = FakeEdge()
    one.plug("", edge)  # type: ignore[arg-type]
    assert one.controls[""].robot is edge
    one.on_token("", True)
    assert edge.asks == 1, "a gateway that came back is asked its parameters"
    one.on_bug("", ValueError("boom"))
    (report,) = edge.errors
    assert report.key == "foxglove:view" and "showing robot failed: ValueError('boom')" in report.reason
    one.on_params("", b"table")
    assert host.tables == [("", b"table")]
    one.on_health("", health(True))
    assert one.controls[""].estop_seen is True and host.pokes >= 2
    one.plug("", NO_EDGE)
    assert one.controls[""].robot is NO_EDGE


def test_the_wiring_asks_the_right_robot_and_answers_a_set_no_session_can_carry() -> None:
    host = FakeHost()
    fleet_reports: list[ErrorReport] = []
    both = wiring(host, "r1", "r2", reporter=ErrorReporter("foxglove", fleet_reports.append, lambda: 1000.0))
    edge = FakeEdge()
    both.plug("r1", edge)  # type: ignore[arg-type]
    both.ask_params("r1")
    both.set_params("r1", 3, b"{}")
    both.set_params("r2", 4, b"{}")
    assert edge.asks == 1 and edge.sets == [(3, b"{}")]
    assert host.replies == [("r2", (4, None, None))], "no edge: the set ends unanswered at once"
    assert both.latest_pose("r1") == b"pose" and both.latest_pose("r2") is None and both.latest_pose("r9") is None
    both.report("r1", "parameters", "bad value", "", now=5.0)
    both.report(None, "parameters", "names no robot", "", now=5.0)
    assert [r.reason for r in edge.errors] == ["bad value"] and [r.reason for r in fleet_reports] == ["names no robot"]


def test_the_watch_decides_which_keys_each_edge_follows() -> None:
    host = FakeHost()
    one = wiring(host, "")
    edge = FakeEdge()
    one.plug("", edge)  # type: ignore[arg-type]
    one.watch_changed()
    assert edge.wanted == set(), "nobody watches: nothing is followed"
    one.watch.subscribe(1, "/odometry")
    one.watch_changed()
    assert edge.wanted == {"robot/pose"}


@pytest.mark.slow
def test_prefix_with_fleet_ends_in_one_sentence(tmp_path: Path) -> None:
    path = tmp_path / "fleet.toml"
    path.write_text('[[robot]]\nid = "r1"\ncontrol_port = 1\nlog_port = 2\n')
    command = [sys.executable, "-m", "blackmetal", "foxglove", "--fleet", str(path), "--prefix", "fleet/r1"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "--prefix is for one robot and cannot be used with --fleet" in result.stderr


# --------------------------------------------------------------------------- on Zenoh: three robots, one view
class FleetClient(FoxClient):
    """A Foxglove client that also reads every channel advertised and subscribes."""

    def channels(self) -> dict[str, dict[str, Any]]:
        return {c["topic"]: c for op in self.ops if op["op"] == "advertise" for c in op["channels"]}

    def subscribe(self, subscription: int, topic: str) -> None:
        channel = self.channels()[topic]["id"]
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": subscription, "channelId": channel}]}))


def _zargs(port: int) -> list[str]:
    return ["-e", f"tcp/127.0.0.1:{port}", "--no-multicast-scouting"]


def _truths(session: zenoh.Session) -> dict[str, Pose]:
    found: dict[str, Pose] = {}
    for reply in session.get("fleet/*/sim/truth", timeout=5):
        if reply.ok is not None:
            found[str(reply.ok.key_expr).split("/")[1]] = decode(Pose, reply.ok.payload.to_bytes())
    assert set(found) == set(IDS), found
    return found


def _estops(session: zenoh.Session) -> dict[str, bool]:
    found: dict[str, bool] = {}
    for reply in session.get("fleet/*/gateway/health", timeout=5):
        if reply.ok is not None:
            found[str(reply.ok.key_expr).split("/")[1]] = decode(GatewayHealth, reply.ok.payload.to_bytes()).estop
    return found


@pytest.mark.integration
def test_one_view_shows_and_drives_a_fleet_of_three(children: list[Child], tmp_path: Path) -> None:
    port = free_port()
    fleet = tmp_path / "fleet.toml"
    sim = Child(["-m", "blackmetal", "sim", "--robots", str(len(IDS)), "--write-fleet", str(fleet), *zenoh_listen_args(port)])  # the hub
    children.append(sim)
    sim.ready()
    gateway = Child(["-m", "blackmetal.gateway", "--fleet", str(fleet), "--poll-hz", "50", *_zargs(port)])
    odometry = Child(["-m", "blackmetal.odometry_service", "--fleet", str(fleet), *_zargs(port)])
    view = Child(["-m", "blackmetal", "foxglove", "--fleet", str(fleet), "--port", "0", *_zargs(port)])
    children += [gateway, odometry, view]
    gateway.ready()
    odometry.ready()
    info = view.ready()
    assert info["prefixes"] == [f"fleet/{rid}" for rid in IDS]
    assert info["robots"]["r3"] == {"prefix": "fleet/r3", "namespace": "/r3", "frames": ["r3/odom", "r3/base_link"]}

    with zenoh.open(client_config(port)) as session:
        errors: dict[str, list[ErrorReport]] = defaultdict(list)
        lock = threading.Lock()

        def on_error(sample: zenoh.Sample) -> None:
            with lock:
                errors[str(sample.key_expr).split("/")[1]].append(decode(ErrorReport, sample.payload.to_bytes()))

        session.declare_subscriber("fleet/*/errors", on_error)
        client = FleetClient(info["url"])
        try:
            # every robot's channels and services, one /tf, the fleet's summary
            per_robot = {"pose", "odometry", "path", "truth/pose", "wheels", "health", "diagnostics", "errors", "log"}
            expected = {f"/{rid}/{name}" for rid in IDS for name in per_robot} | {"/tf", "/fleet/summary", "/fleet/log"}
            client.wait(lambda: expected <= set(client.channels()), "every robot's channels")
            assert "/pose" not in client.channels() and not any(t.startswith("/r1/tf") for t in client.channels())
            assert set(client.services) == {f"/{rid}/{s.value}" for rid in IDS for s in Service}

            # /r2/pose in r2's frame, every robot's transform on /tf, the summary with three rows
            client.subscribe(1, "/r2/pose")
            client.subscribe(2, "/tf")
            client.subscribe(3, "/fleet/summary")
            pose_class = protobuf_class(client.channels()["/r2/pose"])
            tf_class = protobuf_class(client.channels()["/tf"])
            client.wait(lambda: len(client.messages[1]) >= 5, "/r2/pose messages")
            assert {pose_class.FromString(m).frame_id for m in client.messages[1]} == {"r2/odom"}

            def frames() -> set[tuple[str, str]]:
                return {(t.parent_frame_id, t.child_frame_id) for t in map(tf_class.FromString, client.messages[2])}

            poses = {(f"{rid}/odom", f"{rid}/base_footprint") for rid in IDS} | {
                (f"{rid}/base_footprint", f"{rid}/base_link") for rid in IDS
            }
            client.wait(lambda: poses <= frames(), "every robot's transform, to its URDF's root")
            wheels = {(f"{rid}/base_link", f"{rid}/{wheel}") for rid in IDS for wheel in ("left_wheel", "right_wheel", "caster")}
            client.wait(lambda: wheels <= frames(), "every robot's wheels turning")
            assert len(frames()) == 15, "one tree per robot: no frame with two parents"

            def summary() -> dict[str, Any] | None:
                last = json.loads(client.messages[3][-1]) if client.messages[3] else None
                return last if last and last["robots_up"] == 3 else None

            rows = client.wait(summary, "a summary with three robots up")["robots"]
            assert [row["id"] for row in rows] == list(IDS) and all(row["poll_hz"] > 0 for row in rows)

            # a Twist on /r3/cmd_vel moves r3 alone
            before = _truths(session)
            client.advertise(10, "/r3/cmd_vel", "geometry_msgs/msg/Twist")
            end = time.monotonic() + 3.0  # three summary periods (1 s each, on health at 1 Hz): one shows foxglove driving, loaded or not
            while time.monotonic() < end:
                client.publish(10, TWIST_FORWARD)
                client.pump(0.1)
            wait_for(lambda: _truths(session)["r3"].x - before["r3"].x > 0.15, what="r3 to drive forward")
            after = _truths(session)
            assert all((after[rid].x, after[rid].y) == (before[rid].x, before[rid].y) for rid in ("r1", "r2")), (before, after)
            client.wait(
                lambda: any(json.loads(m)["driving"].get("r3") == COMMAND_SOURCE for m in client.messages[3]),
                "the summary: foxglove drives r3",
            )

            # /r1/set_estop engages r1's e-stop alone, and the summary shows it
            response, failure = client.call("/r1/set_estop", b'{"data": true}')
            assert failure is None and response is not None and response["success"], failure
            assert _estops(session) == {"r1": True, "r2": False, "r3": False}
            client.wait(lambda: json.loads(client.messages[3][-1])["estop"] == ["r1"], "the summary: r1's e-stop")
            response, failure = client.call("/r1/set_estop", b'{"data": false}')
            assert failure is None and response is not None and "released" in response["message"]
            assert not any(_estops(session).values())

            # a bad message for r2 is refused and reported on fleet/r2/errors alone; r2 keeps posing in the view
            client.advertise(11, "/r2/cmd_vel", "geometry_msgs/msg/Twist")
            client.publish(11, b"{not json")
            client.wait(lambda: any("/r2/cmd_vel" in s["message"] for s in client.statuses()), "the status for /r2/cmd_vel")

            def reported() -> bool:
                with lock:
                    return any(e.source == "foxglove" and "not valid JSON" in e.reason for e in errors["r2"])

            wait_for(reported, what="the report on fleet/r2/errors")
            with lock:
                assert not any(e.source == "foxglove" for rid in ("r1", "r3") for e in errors[rid])
            seen = len(client.messages[1])
            client.wait(lambda: len(client.messages[1]) >= seen + 10, "r2 to keep posing")
        finally:
            client.close()
    assert view.stop() == 0
