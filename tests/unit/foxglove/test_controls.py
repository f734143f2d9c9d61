"""What Foxglove clients may do: drive on /cmd_vel, stop on /estop, call set_estop and reset_odometry; refusals; subprotocols.

The pure parts run on a fake clock in milliseconds (the handshake rewrite,
the frame tap, :class:`Controls`); the rest against real processes (sim,
gateway, odometry, ``blackmetal foxglove``) with a WebSocket client that
speaks Foxglove's protocol as the app, the Teleop, Publish and Service Call
panels do.
"""

from __future__ import annotations

import itertools
import json
import struct
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from typing import Any

import pytest
import zenoh
from helpers import Child, client_config, free_port, start_robot, wait_for, zenoh_connect_args
from websockets.exceptions import InvalidStatus
from websockets.sync.client import ClientConnection, connect

from blackmetal.foxglove.controls import ASK_PERIOD_S, Controls
from blackmetal.foxglove.front import (
    LEGACY_SUBPROTOCOL,
    SDK_SUBPROTOCOL,
)
from blackmetal.foxglove.naming import COMMAND_SOURCE, ServerRefusal, StatusLevel
from blackmetal.schemas import ErrorReport, EStop, GatewayHealth, Keys, LinkHealth, Pose, Twist, decode, encode

KEYS = Keys("robot")
TWIST_FORWARD = json.dumps({"linear": {"x": 0.3, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}).encode()


# --------------------------------------------------------------------------- the handshake


# --------------------------------------------------------------------------- the frame tap


# --------------------------------------------------------------------------- Controls, on a fake clock
class Bench:
    """Everything a Controls core sends, by kind."""

    def __init__(self) -> None:
        self.commands: list[tuple[str, bytes]] = []
        self.health_asks = 0
        self.resets: list[tuple[int, bytes]] = []
        self.nav: list[tuple[str, int, bytes]] = []
        self.statuses: list[tuple[int | None, StatusLevel, str]] = []
        self.answers: dict[int, tuple[bytes | None, str | None]] = {}
        self.errors: list[ErrorReport] = []

    def command(self, key: str, payload: bytes) -> None:
        self.commands.append((key, payload))

    def ask_health(self) -> None:
        self.health_asks += 1

    def ask_reset(self, call: int, payload: bytes) -> None:
        self.resets.append((call, payload))

    def ask_nav(self, key: str, call: int, payload: bytes) -> None:
        self.nav.append((key, call, payload))

    def status(self, client: int | None, level: StatusLevel, message: str) -> None:
        self.statuses.append((client, level, message))

    def answer(self, call: int, response: bytes | None, failure: str | None) -> None:
        assert call not in self.answers, "a call is answered once"
        self.answers[call] = (response, failure)

    def error(self, message: ErrorReport) -> None:
        self.errors.append(message)

    def estops(self) -> list[bool]:
        puts = [(key, decode(EStop, payload).engaged) for key, payload in self.commands if key in (KEYS.estop, KEYS.estop_release)]
        assert all(key == KEYS.estop_for(engaged) for key, engaged in puts), puts  # a release goes where a safety role puts
        return [engaged for _, engaged in puts]


def waiting(core: Controls) -> int:
    """The calls still waiting for their confirmation."""
    return len(core._estop_calls) + len(core._reset_calls)


def health(estop: bool) -> bytes:
    return encode(GatewayHealth(stamp=1.0, control=LinkHealth("connected"), log=LinkHealth("connected"), estop=estop))


@pytest.fixture
def controls() -> tuple[Controls, Bench]:
    bench = Bench()
    return Controls(KEYS, bench, call_timeout=2.0, wallclock=lambda: 1000.0, robot=bench), bench


def test_cmd_vel_drives_as_the_source_foxglove_and_stops_when_its_publisher_goes(controls: tuple[Controls, Bench]) -> None:
    core, bench = controls
    core.on_advertise(3, 1, "/cmd_vel", "json", "geometry_msgs/Twist", 0.0)  # Lichtblick's Teleop says ROS 1's name
    core.on_message(3, 1, TWIST_FORWARD, 0.1)
    assert bench.commands == [(KEYS.cmd_vel_of(COMMAND_SOURCE), encode(decode(Twist, TWIST_FORWARD)))]
    assert KEYS.cmd_vel_of(COMMAND_SOURCE) == "robot/cmd_vel/foxglove"
    core.on_client_gone(3, 0.2)
    assert bench.commands[-1] == (KEYS.cmd_vel_of(COMMAND_SOURCE), encode(Twist()))
    assert not bench.statuses and not bench.errors


def test_the_3d_panels_own_topics_are_taken_and_a_goal_reaches_the_navigation_service(controls: tuple[Controls, Bench]) -> None:
    core, bench = controls
    shown: list[tuple[StatusLevel, str]] = []
    core.nav.show = lambda level, message: shown.append((level, message))
    panel = {  # what Foxglove's 3D panel advertises as it opens (ROS 1's schema names)
        1: ("/move_base_simple/goal", "geometry_msgs/PoseStamped"),
        2: ("/clicked_point", "geometry_msgs/PointStamped"),
        3: ("/initialpose", "geometry_msgs/PoseWithCovarianceStamped"),
        4: ("/goal_pose", "geometry_msgs/msg/PoseStamped"),
    }
    for channel, (topic, schema) in panel.items():
        core.on_advertise(6, channel, topic, "json", schema, 0.0)
    assert not bench.statuses and not bench.errors, "no problem in the app for opening a 3D panel"
    goal = b'{"header": {"frame_id": "odom"}, "pose": {"position": {"x": 2.0, "y": 1.0}, "orientation": {"z": 1.0, "w": 0.0}}}'
    core.on_message(6, 4, goal, 0.1)
    ((key, call, payload),) = bench.nav
    assert key == "robot/nav/goal" and json.loads(payload) == {
        "x": 2.0,
        "y": 1.0,
        "yaw": pytest.approx(3.141592653589793),
        "frame": "odom",
        "goal_id": None,
    }
    core.on_nav_reply(call, b'{"accepted": true, "goal_id": "' + b"c" * 32 + b'", "reason": ""}', None, 0.2)
    assert shown == [(StatusLevel.INFO, f"goal (2.00, 1.00) facing 180 deg in odom: accepted as {'c' * 32}")]
    core.on_message(6, 1, goal.replace(b"odom", b"r9/odom"), 0.3)
    assert len(bench.nav) == 1 and "not this robot's" in bench.statuses[-1][2] and bench.errors[-1].key == "foxglove:/move_base_simple/goal"
    core.on_message(6, 4, goal, 0.4)
    assert core.next_deadline() == pytest.approx(2.4), "a goal waits for its answer at most the call timeout"
    core.tick(2.4)
    assert "did not answer within 2 s" in shown[-1][1] and core.next_deadline() > 2.4
    core.on_service_call(9, 6, "cancel_goal", b"{}", 2.5)
    assert bench.nav[-1][0] == "robot/nav/cancel"
    core.on_nav_reply(bench.nav[-1][1], b'{"canceled": [], "reason": "no goal runs"}', None, 2.6)
    assert bench.answers[9] == (b'{"success": false, "message": "nothing canceled: no goal runs"}', None)
    core.on_advertise(6, 5, "/goal_pose", "json", "geometry_msgs/msg/Twist", 0.5)
    assert "/goal_pose carries geometry_msgs/msg/PoseStamped or geometry_msgs/PoseStamped" in bench.statuses[-1][2]


@pytest.mark.parametrize(
    ("topic", "encoding", "schema", "payload", "words"),
    [
        ("/cmd_vel", "json", "geometry_msgs/msg/Twist", b"{bad json", "not valid JSON"),
        ("/cmd_vel", "json", "geometry_msgs/msg/Twist", b'{"linear": {"X": 1}}', "X"),
        ("/cmd_vel", "cdr", "geometry_msgs/msg/Twist", b"\x00\x01", "json-encoded"),
        ("/cmd_vel", "json", "std_msgs/msg/Bool", b'{"data": true}', "geometry_msgs/msg/Twist"),
        ("/foo", "json", "std_msgs/msg/String", b'{"data": "x"}', "not taken here"),
    ],
)
def test_a_refused_client_message_gets_a_status_and_a_report_and_moves_nothing(
    controls: tuple[Controls, Bench], topic: str, encoding: str, schema: str, payload: bytes, words: str
) -> None:
    core, bench = controls
    core.on_advertise(5, 2, topic, encoding, schema, 0.0)
    core.on_message(5, 2, payload, 0.1)
    assert not bench.commands
    assert bench.statuses and all(client == 5 and level is StatusLevel.ERROR for client, level, _ in bench.statuses)
    assert any(words in message for _, _, message in bench.statuses)
    assert bench.errors and bench.errors[-1].source == "foxglove" and words in bench.errors[-1].reason


def test_statuses_to_a_flooding_client_are_throttled_reports_rate_limited(controls: tuple[Controls, Bench]) -> None:
    core, bench = controls
    core.on_advertise(5, 2, "/cmd_vel", "json", "geometry_msgs/msg/Twist", 0.0)
    for i in range(100):
        core.on_message(5, 2, b"nonsense", i * 0.01)
    assert len(bench.statuses) == 1 and len(bench.errors) <= 10 + 5  # a burst of 10, then 5 a second
    core.tick(2.0)
    assert bench.errors[-1].suppressed > 0


def test_the_estop_topic_engages_releases_only_on_an_explicit_false_and_fails_safe(controls: tuple[Controls, Bench]) -> None:
    core, bench = controls
    core.on_advertise(1, 4, "/estop", "json", "std_msgs/msg/Bool", 0.0)
    for payload in [b'{"data": true}', b'{"data": false}', b'{"data": "false"}', b"{}", b'{"data": 0}', b"garbage", b'{"data": false}']:
        core.on_message(1, 4, payload, 0.0)
    assert bench.estops() == [True, False, True, True, True, True, False]
    assert len(bench.errors) == 4 and all('only {"data": false} releases' in e.reason for e in bench.errors)


def test_set_estop_answers_once_the_gateways_health_confirms(controls: tuple[Controls, Bench]) -> None:
    core, bench = controls
    core.on_health(health(False), 0.0)
    core.on_service_call(1, 7, "set_estop", b'{"data": true}', 0.0)
    assert bench.estops() == [True] and bench.health_asks == 1 and not bench.answers
    core.on_health(health(False), 0.05)  # an older health, still released: no answer yet
    assert not bench.answers
    core.tick(ASK_PERIOD_S)  # the engage is repeated (safe) and health asked again
    assert bench.estops() == [True, True] and bench.health_asks == 2
    core.on_health(health(True), 0.3)
    response, failure = bench.answers[1]
    assert failure is None and response is not None and json.loads(response)["success"] is True
    assert waiting(core) == 0 and core.next_deadline() == float("inf")


def test_a_release_is_sent_once_and_an_unconfirmed_call_fails_at_its_time_limit(controls: tuple[Controls, Bench]) -> None:
    core, bench = controls
    core.on_service_call(2, 7, "set_estop", b'{"data": false}', 0.0)
    now = 0.0
    while 2 not in bench.answers:
        now = core.next_deadline()
        assert now <= 2.0
        core.tick(now)
    assert bench.estops() == [False], "a release is never repeated over someone's later stop"
    _, failure = bench.answers[2]
    assert failure is not None and "did not confirm" in failure and "no health" in failure
    assert bench.errors and bench.errors[-1].key == "foxglove:set_estop"


def test_a_stop_supersedes_a_waiting_release(controls: tuple[Controls, Bench]) -> None:
    core, bench = controls
    core.on_service_call(1, 7, "set_estop", b'{"data": false}', 0.0)
    core.on_advertise(8, 1, "/estop", "json", "std_msgs/msg/Bool", 0.0)
    core.on_message(8, 1, b'{"data": true}', 0.1)
    assert bench.answers[1][1] is not None and "superseded" in str(bench.answers[1][1])
    core.on_health(health(True), 0.2)
    assert bench.estops() == [False, True] and waiting(core) == 0


@pytest.mark.parametrize("payload", [b'{"data": "yes"}', b"", b"{}"])
def test_a_malformed_set_estop_fails_and_engages(controls: tuple[Controls, Bench], payload: bytes) -> None:
    core, bench = controls
    core.on_service_call(1, 7, "set_estop", payload, 0.0)
    assert bench.estops() == [True] and bench.answers[1][1] is not None and bench.errors


def test_reset_odometry_answers_with_the_odometrys_pose_or_its_reason(controls: tuple[Controls, Bench]) -> None:
    core, bench = controls
    core.on_service_call(1, 7, "reset_odometry", b"", 0.0)
    core.on_service_call(2, 7, "reset_odometry", b'{"x": 1.5, "yaw": 0.5}', 0.0)
    core.on_service_call(3, 7, "reset_odometry", b'{"x": "far"}', 0.0)
    core.on_service_call(4, 7, "reset_odometry", b"{}", 0.0)
    core.on_service_call(5, 7, "reset_odometry", b"{}", 0.0)
    assert [call for call, _ in bench.resets] == [1, 2, 4, 5] and json.loads(bench.resets[1][1])["x"] == 1.5
    core.on_reset_reply(1, encode(Pose(stamp=1.0, x=0.0, y=0.0, yaw=0.0)), None, 0.1)
    core.on_reset_reply(1, None, None, 0.1)
    core.on_reset_reply(2, None, b"invalid PoseReset: reset refused", 0.1)
    core.on_reset_reply(4, None, None, 0.1)  # nobody answered
    response, failure = bench.answers[1]
    assert failure is None and response is not None and json.loads(response)["pose"]["x"] == 0.0
    assert "reset refused" in str(bench.answers[2][1]) and bench.answers[3][1] is not None and "no odometry" in str(bench.answers[4][1])
    core.tick(2.0)
    assert "did not answer within 2 s" in str(bench.answers[5][1]) and waiting(core) == 0
    assert {e.key for e in bench.errors} == {"foxglove:reset_odometry"}


def test_refusals_the_server_made_itself_are_reported_and_a_failed_call_also_gets_a_status(controls: tuple[Controls, Bench]) -> None:
    core, bench = controls
    core.on_server_refusal(4, ServerRefusal.STATUS, "Unknown channel ID: 9", 0.0)
    assert not bench.statuses and "Unknown channel ID: 9" in bench.errors[-1].reason
    core.on_server_refusal(4, ServerRefusal.SERVICE_CALL_FAILURE, "Unknown service (service id 99, call 1)", 0.0)
    assert bench.statuses == [(4, StatusLevel.ERROR, "blackmetal refused a service call: Unknown service (service id 99, call 1)")]
    assert len(bench.errors) == 2


# --------------------------------------------------------------------------- against the real processes
class FoxClient:
    """A WebSocket client that speaks Foxglove's protocol as the app does: advertise and publish JSON, call services."""

    def __init__(self, url: str, subprotocols: list[str] | None = None) -> None:
        offered = subprotocols or [SDK_SUBPROTOCOL, LEGACY_SUBPROTOCOL]
        self._stack = ExitStack()
        self.ws: ClientConnection = self._stack.enter_context(connect(url, subprotocols=offered, open_timeout=20))  # type: ignore[arg-type]
        self.ops: list[dict[str, Any]] = []
        self.responses: dict[int, bytes] = {}
        self.services: dict[str, int] = {}
        #: Subscription id -> the payloads of its message data (a client that subscribes reads them).
        self.messages: dict[int, list[bytes]] = defaultdict(list)
        self._calls = itertools.count(1)
        self.wait(lambda: self.server_info and len(self.services) >= 2, "serverInfo and the services")

    @property
    def server_info(self) -> dict[str, Any] | None:
        return next((op for op in self.ops if op["op"] == "serverInfo"), None)

    def statuses(self) -> list[dict[str, Any]]:
        return [op for op in self.ops if op["op"] == "status"]

    def pump(self, timeout: float = 0.05) -> None:
        try:
            message = self.ws.recv(timeout=timeout)
        except TimeoutError:
            return
        if isinstance(message, str):
            op = json.loads(message)
            self.ops.append(op)
            if op["op"] == "advertiseServices":
                self.services.update({service["name"]: service["id"] for service in op["services"]})
        elif message[0] == 0x01:  # message data: subscription id, log time, payload
            (subscription,) = struct.unpack_from("<I", message, 1)
            self.messages[subscription].append(message[13:])
        elif message[0] == 0x03:  # service call response
            _, call, size = struct.unpack_from("<III", message, 1)
            self.responses[call] = message[13 + size :]

    def wait(self, condition: Callable[[], Any], what: str, timeout: float = 20.0) -> Any:
        deadline = time.monotonic() + timeout
        while not (value := condition()):
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out waiting for {what}; received {[str(op)[:300] for op in self.ops[-5:]]}")
            self.pump()
        return value

    def advertise(self, channel: int, topic: str, schema: str) -> None:
        self.ws.send(
            json.dumps({"op": "advertise", "channels": [{"id": channel, "topic": topic, "encoding": "json", "schemaName": schema}]})
        )

    def publish(self, channel: int, payload: bytes) -> None:
        self.ws.send(b"\x01" + struct.pack("<I", channel) + payload)

    def call(self, name: str, payload: bytes, service: int | None = None) -> tuple[dict[str, Any] | None, str | None]:
        """(response, None) or (None, the failure's message)."""
        call = next(self._calls)
        self.ws.send(b"\x02" + struct.pack("<III", self.services[name] if service is None else service, call, 4) + b"json" + payload)

        def answered() -> tuple[dict[str, Any] | None, str | None] | None:
            if call in self.responses:
                return json.loads(self.responses[call]), None
            failure = next((op for op in self.ops if op["op"] == "serviceCallFailure" and op["callId"] == call), None)
            return (None, failure["message"]) if failure else None

        return self.wait(answered, f"the answer to {name}")

    def close(self) -> None:
        self._stack.close()


class Robot:
    """The simulated robot, its gateway and odometry, ``blackmetal foxglove``, and a Zenoh session that watches errors and asks health."""

    def __init__(self) -> None:
        self.children: list[Child] = []
        self.zport = free_port()
        start_robot(self.children, self.zport)
        view = Child(["-m", "blackmetal", "foxglove", "--port", "0", *zenoh_connect_args(self.zport)])
        self.children.append(view)
        self.url = view.ready()["url"]
        self.session = zenoh.open(client_config(self.zport))
        self.errors: list[ErrorReport] = []
        self._lock = threading.Lock()
        self.session.declare_subscriber(KEYS.errors, self._on_error)

    def _on_error(self, sample: zenoh.Sample) -> None:
        report = decode(ErrorReport, sample.payload.to_bytes())
        with self._lock:
            self.errors.append(report)

    def reports(self, words: str) -> list[ErrorReport]:
        with self._lock:
            return [e for e in self.errors if e.source == "foxglove" and words in e.reason]

    def health(self) -> GatewayHealth:
        replies = [r for r in self.session.get(KEYS.health, timeout=5) if r.ok is not None]
        return decode(GatewayHealth, replies[0].ok.payload.to_bytes())

    def pose(self) -> Pose:
        replies = [r for r in self.session.get(KEYS.pose, timeout=5) if r.ok is not None]
        return decode(Pose, replies[0].ok.payload.to_bytes())

    def close(self) -> None:
        self.session.close()
        for child in reversed(self.children):
            child.stop()


@pytest.fixture(scope="module")
def robot() -> Iterator[Robot]:
    robot = Robot()
    yield robot
    robot.close()


@pytest.fixture
def client(robot: Robot) -> Iterator[FoxClient]:
    client = FoxClient(robot.url)
    yield client
    client.close()


@pytest.mark.integration
def test_a_client_offering_only_foxglove_websocket_v1_connects(robot: Robot) -> None:
    for offered in ([LEGACY_SUBPROTOCOL], [SDK_SUBPROTOCOL], [LEGACY_SUBPROTOCOL, SDK_SUBPROTOCOL]):
        client = FoxClient(robot.url, offered)
        try:
            assert client.ws.subprotocol == offered[0] if len(offered) == 1 else client.ws.subprotocol in offered
            info = client.server_info
            assert info is not None and info["name"] == "blackmetal"
            assert {"clientPublish", "services"} <= set(info["capabilities"]) and info["supportedEncodings"] == ["json"]
            assert set(client.services) == {"set_estop", "reset_odometry", "cancel_goal"}
        finally:
            client.close()
    with pytest.raises(InvalidStatus) as refused:
        connect(robot.url, subprotocols=["other.v1"], open_timeout=20)  # type: ignore[list-item]
    assert refused.value.response.status_code == 400


@pytest.mark.integration
def test_a_client_drives_on_cmd_vel_with_json_and_calls_both_services(robot: Robot, client: FoxClient) -> None:
    response, failure = client.call("set_estop", b'{"data": false}')
    assert failure is None and response == {"success": True, "message": response["message"]} and not robot.health().estop
    response, failure = client.call("reset_odometry", b"{}")
    assert failure is None and response is not None and response["success"] and response["pose"]["x"] == 0.0

    client.advertise(1, "/cmd_vel", "geometry_msgs/msg/Twist")  # what Foxglove's Teleop panel advertises
    active: set[str | None] = set()
    end = time.monotonic() + 2.5
    while time.monotonic() < end:  # the Teleop panel's 10 Hz
        client.publish(1, TWIST_FORWARD)
        client.pump(0.1)
        if time.monotonic() > end - 1.5:
            active.add(robot.health().active_source)
    assert active == {COMMAND_SOURCE}, active
    assert wait_for(lambda: robot.pose().x > 0.2, what="the robot to drive forward")
    assert not client.statuses()

    response, failure = client.call("set_estop", b'{"data": true}')
    assert failure is None and response is not None and "engaged" in response["message"] and robot.health().estop
    response, failure = client.call("set_estop", b'{"data": false}')
    assert failure is None and response is not None and "released" in response["message"] and not robot.health().estop
    response, failure = client.call("reset_odometry", b'{"x": 1.0, "y": 2.0, "yaw": 0.5}')
    assert failure is None and response is not None and (response["pose"]["x"], response["pose"]["y"]) == (1.0, 2.0)
    assert wait_for(lambda: abs(robot.pose().x - 1.0) < 0.05, what="the reset pose")


@pytest.mark.integration
def test_the_estop_topic_engages_and_only_an_explicit_false_releases(robot: Robot, client: FoxClient) -> None:
    client.advertise(2, "/estop", "std_msgs/msg/Bool")  # the Publish panel's button
    client.publish(2, b'{"data": true}')
    wait_for(lambda: robot.health().estop, what="the e-stop engaged")
    for payload in (b'{"data": "false"}', b"{}", b"false"):
        client.publish(2, payload)
    time.sleep(0.3)
    assert robot.health().estop, "no malformed release releases"
    client.wait(lambda: any('only {"data": false} releases' in s["message"] for s in client.statuses()), "the status")
    wait_for(lambda: robot.reports('only {"data": false} releases'), what="the report")
    client.publish(2, b'{"data": false}')
    wait_for(lambda: not robot.health().estop, what="the e-stop released")


@pytest.mark.integration
def test_malformed_or_unknown_client_messages_get_a_status_and_a_report(robot: Robot, client: FoxClient) -> None:
    bystander = FoxClient(robot.url)
    try:
        client.advertise(1, "/cmd_vel", "geometry_msgs/msg/Twist")
        client.advertise(3, "/unknown", "std_msgs/msg/String")
        client.publish(1, b"{not json")
        client.publish(3, b'{"data": "hello"}')
        client.publish(42, b"{}")  # a channel it never advertised
        _, failure = client.call("unknown", b"{}", service=999)
        assert failure == "Unknown service"
        expected = {
            "not valid JSON": "not valid JSON",
            "/unknown": "not taken here",
            "42": "Unknown channel ID: 42",
            "999": "Unknown service",
        }
        for what, words in expected.items():
            client.wait(lambda words=words: any(words in s["message"] for s in client.statuses()), f"a status on {what}")
            wait_for(lambda words=words: robot.reports(words), what=f"a report on {what}")
        bystander.pump(0.5)
        assert not bystander.statuses(), "statuses go to the client that sent the message only"
    finally:
        bystander.close()
