"""The gateway's parameters and the robot model in Foxglove (#28 item 5).

Pure, on a fake clock: :class:`Parameters` shows each gateway's table under
Foxglove's names (a fleet's under ``/<id>/``), sends a set to the robot's
gateway alone through ``<prefix>/gateway/params/set``, and answers with the
values after; a refusal reaches the client as a status with the gateway's
reason and the answer shows the value it kept. The URDF's wheel joints turn
as the impulses say. Against real processes: a client (Foxglove's protocol,
as the app) reads the parameters, sets ``max_wheel_speed`` (the gateway
takes it), is refused one out of range (status with the reason, the value
unchanged), receives the URDF that urdfdom accepts, and sees the wheels
turn on ``/tf`` and ``/joint_states`` while the robot drives.
"""

from __future__ import annotations

import json
import math
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from helpers import Child, client_config, free_port, start_robot, zenoh_connect_args

from blackmetal.foxglove.model import moving_joints
from blackmetal.foxglove.naming import StatusLevel
from blackmetal.foxglove.params import Parameters, param_name
from blackmetal.robot_model import WHEEL_SEPARATION
from blackmetal.schemas import GatewayParams, Keys, Param, ParamResult, ParamsSet, ParamsSetReply, decode, encode
from unit.foxglove.test_controls import TWIST_FORWARD
from unit.foxglove.test_fleet import FleetClient
from unit.foxglove.test_live import protobuf_class
from unit.tools.test_urdf import check_urdf


def table(max_wheel_speed: float = 0.8, separation: float = WHEEL_SEPARATION) -> list[Param]:
    return [
        Param("max_wheel_speed", "double", max_wheel_speed, min=0.01, max=0.8),
        Param("sources.nav.priority", "integer", 10, min=0, max=255),
        Param("wheel_separation", "double", separation, read_only=True),
        Param("robot", "string", "127.0.0.1:665", read_only=True),
    ]


class Out:
    """Everything :class:`Parameters` sends, by kind."""

    def __init__(self) -> None:
        self.asks: list[str] = []
        self.sets: list[tuple[str, int, bytes]] = []
        self.statuses: list[tuple[int | None, StatusLevel, str]] = []
        self.answers: dict[int, list[Param]] = {}
        self.changed: list[list[Param]] = []
        self.reports: list[tuple[str | None, str]] = []

    def ask_params(self, robot_id: str) -> None:
        self.asks.append(robot_id)

    def set_params(self, robot_id: str, call: int, payload: bytes) -> None:
        self.sets.append((robot_id, call, payload))

    def status(self, client: int | None, level: StatusLevel, message: str) -> None:
        self.statuses.append((client, level, message))

    def parameters_answer(self, call: int, values: list[Param]) -> None:
        assert call not in self.answers, "a set is answered once"
        self.answers[call] = values

    def parameters_changed(self, values: list[Param]) -> None:
        self.changed.append(values)

    def report(self, robot_id: str | None, topic: str, reason: str, text: str, now: float) -> None:
        self.reports.append((robot_id, reason))


def test_one_robots_parameters_are_the_gateways_and_a_refusal_says_why_and_keeps_the_value() -> None:
    out = Out()
    params = Parameters({"": (Keys("robot"), "")}, out, call_timeout=2.0)
    params.gateways = out
    params.on_table("", encode(GatewayParams(stamp=1.0, params=table())), now=0.0)
    assert [p.name for p in params.values()] == ["max_wheel_speed", "sources.nav.priority", "wheel_separation", "robot"]
    assert len(out.changed) == 1 and params.values(["max_wheel_speed"])[0].value == 0.8
    params.on_table("", encode(GatewayParams(stamp=2.0, params=table())), now=0.1)
    assert len(out.changed) == 1, "an unchanged table sends nothing"

    params.on_set(1, 7, [("max_wheel_speed", 0.3), ("wheel_separation", 0.6)], now=1.0)
    ((robot, call, payload),) = out.sets
    assert (robot, call) == ("", 1) and decode(ParamsSet, payload).values == {"max_wheel_speed": 0.3, "wheel_separation": 0.6}
    assert not out.answers, "answered once the gateway has"
    reason = "wheel_separation is read-only on a running gateway: set it in the gateway's settings and restart it"
    reply = ParamsSetReply(
        [ParamResult("max_wheel_speed", True), ParamResult("wheel_separation", False, reason)],
        GatewayParams(stamp=3.0, params=table(max_wheel_speed=0.3)),
    )
    params.on_set_reply("", 1, encode(reply), None, now=1.01)
    params.on_set_reply("", 1, None, None, now=1.02)  # the query's end: nothing more
    assert {p.name: p.value for p in out.answers[1]} == {"max_wheel_speed": 0.3, "wheel_separation": WHEEL_SEPARATION}
    assert out.statuses == [(7, StatusLevel.ERROR, f"blackmetal: wheel_separation refused by the gateway: {reason}")]
    assert [p.name for p in out.changed[-1]] == ["max_wheel_speed"] and not params._calls


@pytest.mark.parametrize("value", [[1, 2], {"a": 1}, float("nan"), None, b"\x00"])
def test_a_value_no_gateway_parameter_takes_is_refused_by_the_view_and_nothing_is_sent(value: object) -> None:
    out = Out()
    params = Parameters({"": (Keys("robot"), "")}, out)
    params.gateways = out
    params.on_table("", encode(GatewayParams(stamp=1.0, params=table())), now=0.0)
    params.on_set(1, 7, [("max_wheel_speed", value)], now=1.0)
    assert not out.sets and out.answers[1][0].value == 0.8
    assert out.statuses and "takes a number, a bool or a string" in out.statuses[0][2] and out.reports[0][0] == ""


def test_a_fleets_parameters_are_named_per_robot_and_each_set_goes_to_its_gateway_alone() -> None:
    out = Out()
    ids = ("r1", "r2", "r3")
    params = Parameters({rid: (Keys(f"fleet/{rid}"), f"/{rid}") for rid in ids}, out, call_timeout=2.0)
    params.gateways = out
    for rid in ids:
        params.on_table(rid, encode(GatewayParams(stamp=1.0, params=table())), now=0.0)
    assert param_name("/r2", "max_wheel_speed") == "/r2/max_wheel_speed"
    assert "/r2/sources.nav.priority" in {p.name for p in params.values()} and len(params.values()) == 12
    params.on_set(4, 9, [("/r2/max_wheel_speed", 0.2), ("/r9/max_wheel_speed", 0.2), ("max_wheel_speed", 0.2)], now=1.0)
    assert [(robot, decode(ParamsSet, payload).values) for robot, _, payload in out.sets] == [("r2", {"max_wheel_speed": 0.2})]
    assert [robot for robot, _ in out.reports] == [None, None], "names of no robot: the fleet's log"
    params.tick(2.9)
    assert not out.answers
    params.tick(3.0)  # r2's gateway never answered
    assert {p.name: p.value for p in out.answers[4]} == {"/r2/max_wheel_speed": 0.8}
    assert any("did not answer within 2 s" in message for _, _, message in out.statuses)
    assert params.next_deadline() == math.inf


# --------------------------------------------------------------------------- against the real processes
class ParamClient(FleetClient):
    """A Foxglove client that also gets and sets parameters, as the Parameters panel does."""

    def params(self, request_id: str) -> dict[str, Any]:
        answer = self.wait(
            lambda: next((op for op in self.ops if op["op"] == "parameterValues" and op.get("id") == request_id), None),
            f"parameterValues {request_id}",
        )
        return {p["name"]: p["value"] for p in answer["parameters"]}

    def get(self, request_id: str) -> dict[str, Any]:
        self.ws.send(json.dumps({"op": "getParameters", "parameterNames": [], "id": request_id}))
        return self.params(request_id)

    def set(self, request_id: str, name: str, value: Any) -> dict[str, Any]:
        self.ws.send(json.dumps({"op": "setParameters", "parameters": [{"name": name, "value": value}], "id": request_id}))
        return self.params(request_id)


@pytest.fixture(scope="module")
def robot() -> Iterator[tuple[str, int]]:
    children: list[Child] = []
    zport = free_port()
    try:
        start_robot(children, zport)
        view = Child(["-m", "blackmetal", "foxglove", "--port", "0", *zenoh_connect_args(zport)])
        children.append(view)
        yield view.ready()["url"], zport
        assert view.stop() == 0
    finally:
        for child in reversed(children):
            child.stop()


def gateway_max_wheel_speed(session: zenoh.Session) -> float:
    replies = [r for r in session.get("robot/gateway/params", timeout=5) if r.ok is not None]
    return next(float(p.value) for p in decode(GatewayParams, replies[0].ok.payload.to_bytes()).params if p.name == "max_wheel_speed")


@pytest.mark.integration
def test_a_client_reads_and_sets_the_gateways_parameters_and_sees_a_refusal_with_its_reason(robot: tuple[str, int]) -> None:
    url, zport = robot
    client = ParamClient(url)
    try:
        assert "parameters" in (client.server_info or {})["capabilities"]
        shown = client.wait(lambda: (got := client.get(f"g{time.monotonic()}")) and "max_wheel_speed" in got and got, "the gateway's table")
        assert shown["max_wheel_speed"] == 0.8 and shown["wheel_separation"] == WHEEL_SEPARATION and "sources.foxglove.priority" in shown
        with zenoh.open(client_config(zport)) as session:
            assert client.set("s1", "max_wheel_speed", 0.3) == {"max_wheel_speed": 0.3}
            assert gateway_max_wheel_speed(session) == 0.3, "the gateway runs with what the client set"
            assert client.set("s2", "max_wheel_speed", 5.0) == {"max_wheel_speed": 0.3}, "refused: shown at the value it kept"
            status = client.wait(lambda: next((s for s in client.statuses() if "max_wheel_speed" in s["message"]), None), "the status")
            assert status["level"] == StatusLevel.ERROR and "must be within 0.01..0.8" in status["message"]
            assert gateway_max_wheel_speed(session) == 0.3
            assert client.set("s3", "wheel_separation", 0.7) == {"wheel_separation": WHEEL_SEPARATION}
            client.wait(lambda: any("read-only" in s["message"] for s in client.statuses()), "the read-only status")
            assert client.set("s4", "max_wheel_speed", 0.8) == {"max_wheel_speed": 0.8}
    finally:
        client.close()


@pytest.mark.integration
def test_a_client_gets_the_urdf_and_sees_the_wheels_turn_while_the_robot_drives(robot: tuple[str, int], tmp_path: Path) -> None:
    url, _ = robot
    client = ParamClient(url)
    try:
        client.wait(lambda: {"/robot_description", "/joint_states", "/tf"} <= set(client.channels()), "the model's channels")
        assert client.channels()["/robot_description"]["schemaName"] == "std_msgs/msg/String"
        client.subscribe(1, "/robot_description")
        description = json.loads(client.wait(lambda: client.messages[1], "the URDF")[0])["data"]
        path = tmp_path / "robot.urdf"
        path.write_text(description)
        checked = subprocess.run([check_urdf(), str(path)], capture_output=True, text=True, timeout=60)
        assert checked.returncode == 0, checked.stdout + checked.stderr
        assert [j.name for j in moving_joints(description)] == ["left_wheel_joint", "right_wheel_joint"]
        client.subscribe(2, "/joint_states")
        client.subscribe(3, "/tf")
        tf_class = protobuf_class(client.channels()["/tf"])
        client.advertise(9, "/cmd_vel", "geometry_msgs/msg/Twist")
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            client.publish(9, TWIST_FORWARD)
            client.pump(0.1)
        states = [json.loads(m) for m in client.messages[2]]
        assert states and states[-1]["name"] == ["left_wheel_joint", "right_wheel_joint"]
        assert all(v > 1.0 for v in states[-1]["velocity"]), "0.3 m/s on a 0.1 m radius: about 3 rad/s each"
        wheel = [t for t in map(tf_class.FromString, client.messages[3]) if t.child_frame_id == "left_wheel"]
        assert wheel and wheel[-1].parent_frame_id == "base_link" and wheel[-1].translation.y == pytest.approx(WHEEL_SEPARATION / 2)
        assert len({round(t.rotation.y, 3) for t in wheel}) > 5, "the left wheel turns"
    finally:
        client.close()
