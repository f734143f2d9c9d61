"""The action through the adapter's Zenoh edge, against a stand-in for the navigation service: rmw_zenoh's keys with
their attachments (get_result held open until the goal ends), free_fleet's plain keys with ``--rmf``, /tf's map -> odom.

The stand-in answers nav/goal, nav/cancel, nav/result and nav/map_pose as the navigation service's schemas say, and
publishes the robot's pose and the goal's feedback; the test plays the ROS client (an rmw_zenoh service client's get
with its 33-byte attachment) and free_fleet (plain gets, no attachment).
"""

from __future__ import annotations

import json
import struct
import threading
import time
from pathlib import Path

import pytest
import zenoh
from helpers import Child, client_config, free_port, wait_for

from blackmetal.ros2 import action_cdr as cdr
from blackmetal.ros2.action_types import NavLayout, nav_topics
from blackmetal.ros2.messages import RosCodec
from blackmetal.ros2.naming import Distro, attachment, parse_attachment, topics
from blackmetal.ros2.ros_types import TF_MESSAGE
from blackmetal.ros2.settings import Ros2Settings
from blackmetal.ros2.zenoh_edge import Ros2Zenoh
from blackmetal.schemas import encode, make_pose
from blackmetal.schemas.navigation import MapPose, NavCancelReply, NavFeedback, NavGoalReply, NavResult, PlanarPose

UUID = bytes(range(1, 17))
GID = bytes(range(100, 116))
SEND_GOAL_HASH = "RIHS01_a4fcb3bee1bf32e21a0e541a943b221aa0826996e2c98f079b47022b256f48b5"
GET_RESULT_HASH = "RIHS01_c407920357d566771e8882b4ef4d1f1a84ee922d609920ccd57faa6d6e391dc5"
SEND_GOAL_KEY = f"0/navigate_to_pose/_action/send_goal/nav2_msgs::action::dds_::NavigateToPose_SendGoal_/{SEND_GOAL_HASH}"
CANCEL_GOAL_HASH = "RIHS01_573d8b0a534451d7bc2ac8c5ffde8ac14b8593b7001175d0cd6516dcbeb8689a"
GET_RESULT_KEY = f"0/navigate_to_pose/_action/get_result/nav2_msgs::action::dds_::NavigateToPose_GetResult_/{GET_RESULT_HASH}"


def goal_request(uuid: bytes, x: float, y: float, frame: str = "map") -> bytes:
    data = frame.encode() + b"\x00"
    body = uuid + struct.pack("<iII", 0, 0, len(data)) + data
    return (
        b"\x00\x01\x00\x00" + body + b"\x00" * (-len(body) % 8) + struct.pack("<7d", x, y, 0, 0, 0, 0, 1) + struct.pack("<I", 1) + b"\x00"
    )


class NavStandIn:
    """What the navigation service answers; ``state`` moves the goal on."""

    def __init__(self, session: zenoh.Session, prefix: str) -> None:
        self.session, self.prefix, self.goals, self.state, self.asked = session, prefix, [], "executing", []  # type: ignore[var-annotated]
        for name, handler in (("goal", self.goal), ("cancel", self.cancel), ("result", self.result), ("map_pose", self.map_pose)):
            session.declare_queryable(f"{prefix}/nav/{name}", handler)

    def goal(self, query: zenoh.Query) -> None:
        asked = json.loads(query.payload.to_bytes()) if query.payload is not None else {}
        self.asked.append(asked)
        self.goals.append(asked.get("goal_id") or "ff" * 16)
        query.reply(query.key_expr, encode(NavGoalReply(accepted=True, goal_id=self.goals[-1])))

    def cancel(self, query: zenoh.Query) -> None:
        self.state = "canceled"
        query.reply(query.key_expr, encode(NavCancelReply(canceled=self.goals[-1:])))

    def result(self, query: zenoh.Query) -> None:
        query.reply(query.key_expr, encode(NavResult(found=False)))

    def map_pose(self, query: zenoh.Query) -> None:
        query.reply(query.key_expr, encode(MapPose(stamp=time.time(), x=10.0, y=0.0, yaw=0.0)))

    def publish(self) -> None:
        now = time.time()
        self.session.put(f"{self.prefix}/pose", encode(make_pose(now, 1.0, 2.0, 0.0)))
        if self.goals:
            pose = PlanarPose(x=1.0, y=2.0, yaw=0.0)
            message = NavFeedback(
                stamp=now,
                goal_id=self.goals[-1],
                state=self.state,
                pose=pose,
                goal=pose,
                distance_remaining=1.0,
                eta=2.0,
                elapsed=1.0,  # type: ignore[arg-type]
            )
            self.session.put(f"{self.prefix}/nav/feedback", encode(message))


def call(session: zenoh.Session, key: str, payload: bytes, extra: bytes | None = None, timeout: float = 10.0) -> tuple[bytes, bytes | None]:
    replies = list(session.get(key, payload=payload, attachment=extra, timeout=timeout))
    assert replies and replies[0].ok is not None, [r.err.payload.to_string() for r in replies if r.err is not None]
    ok = replies[0].ok
    return ok.payload.to_bytes(), None if ok.attachment is None else ok.attachment.to_bytes()


@pytest.mark.integration
@pytest.mark.parametrize("fleet", [False, True], ids=["one robot", "a fleet (feedback drained from rings)"])
def test_the_action_on_rmw_zenoh_and_free_fleets_keys(children: list[Child], tmp_path: Path, fleet: bool) -> None:
    codec = RosCodec()
    port = free_port()
    router = Child(["-m", "blackmetal", "router", "-l", f"tcp/127.0.0.1:{port}", "--no-multicast-scouting"])
    children.append(router)
    router.ready()
    args = ["--rmf", "--rmf-battery", "0.5", "--no-multicast-scouting", "-e", f"tcp/127.0.0.1:{port}"]
    prefix, name, ns = "robot", "robot", ""
    if fleet:  # robot r1 of a fleet file: prefix fleet/r1, namespace /r1, free_fleet's name r1
        (tmp_path / "fleet.toml").write_text('[[robot]]\nid = "r1"\ncontrol_port = 1\nlog_port = 2\n')
        args += ["--fleet", str(tmp_path / "fleet.toml")]
        prefix, name, ns = "fleet/r1", "r1", "r1/"
    ros2 = Child(["-m", "blackmetal", "ros2", *args])
    children.append(ros2)
    send_goal_key, get_result_key = SEND_GOAL_KEY.replace("0/", f"0/{ns}", 1), GET_RESULT_KEY.replace("0/", f"0/{ns}", 1)
    with zenoh.open(client_config(port)) as session:
        nav = NavStandIn(session, prefix)
        ready = ros2.ready()
        node = ready["nodes"]["r1"] if fleet else ready
        assert node["services"]["navigate_to_pose/_action/send_goal"] == send_goal_key
        assert node["rmf"] == {
            "rmf/tf": f"{name}/tf",
            "rmf/battery_state": f"{name}/battery_state",
            **{
                f"rmf/navigate_to_pose/_action/{n}": f"{name}/navigate_to_pose/_action/{n}"
                for n in ("send_goal", "cancel_goal", "get_result", "feedback", "status")
            },
        }
        seen: dict[str, list[bytes]] = {}
        for key in (
            f"{name}/tf",
            f"{name}/battery_state",
            f"{name}/navigate_to_pose/_action/feedback",
            f"{name}/navigate_to_pose/_action/status",
        ):
            session.declare_subscriber(key, lambda s, k=key: seen.setdefault(k, []).append(s.payload.to_bytes()))
        stop = threading.Event()

        def feed() -> None:
            while not stop.wait(0.05):
                nav.publish()

        feeder = threading.Thread(target=feed, daemon=True)
        feeder.start()
        try:
            # free_fleet's tf: map -> odom (from nav/map_pose) then odom -> base_footprint, frames not prefixed
            wait_for(lambda: len(seen.get(f"{name}/tf", [])) >= 3, what=f"{name}/tf")
            transforms = codec.decode(seen[f"{name}/tf"][-1], TF_MESSAGE).transforms
            assert [(t.header.frame_id, t.child_frame_id) for t in transforms] == [("map", "odom"), ("odom", "base_footprint")]
            assert transforms[0].transform.translation.x == 10.0
            wait_for(lambda: seen.get(f"{name}/battery_state"), what=f"{name}/battery_state")
            assert codec.decode(seen[f"{name}/battery_state"][-1], "sensor_msgs/msg/BatteryState").percentage == pytest.approx(0.5)

            # ROS 2: send_goal with rmw_zenoh's attachment, echoed; get_result held open until the goal ends
            response, extra = call(session, send_goal_key, goal_request(UUID, 3.0, 4.0), attachment(1, time.time_ns(), GID))
            assert response[4] == 1 and extra is not None and parse_attachment(extra)[0] == 1 and parse_attachment(extra)[2] == GID
            assert nav.asked[-1] == {"x": 3.0, "y": 4.0, "yaw": 0.0, "frame": "map", "goal_id": UUID.hex()}
            result: list[tuple[bytes, bytes | None]] = []
            waiter = threading.Thread(
                target=lambda: result.append(call(session, get_result_key, b"\x00\x01\x00\x00" + UUID, attachment(2, 0, GID)))
            )
            waiter.start()
            wait_for(lambda: seen.get(f"{name}/navigate_to_pose/_action/feedback"), what="free_fleet's feedback")
            time.sleep(0.3)
            assert not result  # still running: no answer yet

            # free_fleet: get_result at once with EXECUTING; cancel-all; then the held result says CANCELED
            fleet_result, none = call(session, f"{name}/navigate_to_pose/_action/get_result", b"\x00\x01\x00\x00" + UUID)
            assert fleet_result[4] == 2 and none is None
            canceled, _ = call(session, f"{name}/navigate_to_pose/_action/cancel_goal", b"\x00\x01\x00\x00" + bytes(24))
            assert canceled == cdr.cancel_goal_response(0, [(UUID, *struct.unpack_from("<iI", response, 8))])
            waiter.join(timeout=10)
            assert result and result[0][0] == cdr.get_result_response(NavLayout.JAZZY, 5)
            assert result[0][1] is not None and parse_attachment(result[0][1])[0] == 2
            statuses = seen[f"{name}/navigate_to_pose/_action/status"]
            wait_for(lambda: statuses[-1][-1] == 5, what="free_fleet's status: CANCELED")
        finally:
            stop.set()
            feeder.join()


@pytest.mark.integration
def test_an_idle_fleet_node_still_hears_the_navigation(children: list[Child], tmp_path: Path) -> None:
    """A fleet node nobody watches follows only the navigation's feedback, drained at the fleet's idle pace: a held
    get_result still ends with the goal (the ROS side alone, no --rmf: no pose is followed)."""
    port = free_port()
    router = Child(["-m", "blackmetal", "router", "-l", f"tcp/127.0.0.1:{port}", "--no-multicast-scouting"])
    children.append(router)
    router.ready()
    (tmp_path / "fleet.toml").write_text('[[robot]]\nid = "r1"\ncontrol_port = 1\nlog_port = 2\n')
    ros2 = Child(
        ["-m", "blackmetal", "ros2", "--fleet", str(tmp_path / "fleet.toml"), "--no-multicast-scouting", "-e", f"tcp/127.0.0.1:{port}"]
    )
    children.append(ros2)
    cancel_key = "0/r1/navigate_to_pose/_action/cancel_goal/action_msgs::srv::dds_::CancelGoal_/" + CANCEL_GOAL_HASH
    with zenoh.open(client_config(port)) as session:
        nav = NavStandIn(session, "fleet/r1")
        ros2.ready()
        response, _ = call(session, SEND_GOAL_KEY.replace("0/", "0/r1/", 1), goal_request(UUID, 1.0, 0.0), attachment(1, 0, GID))
        assert response[4] == 1
        result: list[tuple[bytes, bytes | None]] = []
        waiter = threading.Thread(
            target=lambda: result.append(
                call(session, GET_RESULT_KEY.replace("0/", "0/r1/", 1), b"\x00\x01\x00\x00" + UUID, attachment(2, 0, GID))
            )
        )
        waiter.start()
        nav.publish()
        time.sleep(0.3)
        assert not result
        canceled, _ = call(session, cancel_key, b"\x00\x01\x00\x00" + UUID + bytes(8), attachment(3, 0, GID))
        assert canceled[4] == 0  # ERROR_NONE: it is canceling
        started = time.monotonic()
        while waiter.is_alive() and time.monotonic() - started < 10:
            nav.publish()  # the service's last feedback: CANCELED
            time.sleep(0.05)
        waiter.join(timeout=1)
        assert result and result[0][0] == cdr.get_result_response(NavLayout.JAZZY, 5)


@pytest.mark.parametrize(
    ("distro", "send_goal", "feedback"),
    [
        ("humble", "TypeHashNotSupported", "TypeHashNotSupported"),
        ("jazzy", SEND_GOAL_HASH, "RIHS01_9d1f6fa2eb975ce733b419ac2e97b134d8ff92b6478b6559feed9a50bdfd82b3"),
        ("kilted", SEND_GOAL_HASH, "RIHS01_9d1f6fa2eb975ce733b419ac2e97b134d8ff92b6478b6559feed9a50bdfd82b3"),
        ("lyrical", SEND_GOAL_HASH, "RIHS01_2c1b4ec1a0e3a53c9aa326aabe717670eeef0ff3d4c3351ff940613b2011728a"),
        ("rolling", SEND_GOAL_HASH, "RIHS01_2c1b4ec1a0e3a53c9aa326aabe717670eeef0ff3d4c3351ff940613b2011728a"),
    ],
)
def test_each_distros_action_keys_and_tokens(session: zenoh.Session, distro: str, send_goal: str, feedback: str) -> None:
    edge = Ros2Zenoh(session, Ros2Settings(namespace="r1"), RosCodec(), distro=Distro(distro))
    try:
        assert edge.service_keys["navigate_to_pose/_action/send_goal"] == (
            f"0/r1/navigate_to_pose/_action/send_goal/nav2_msgs::action::dds_::NavigateToPose_SendGoal_/{send_goal}"
        )
        assert edge.data_keys["navigate_to_pose/_action/feedback"] == (
            f"0/r1/navigate_to_pose/_action/feedback/nav2_msgs::action::dds_::NavigateToPose_FeedbackMessage_/{feedback}"
        )
        status = [t for t in edge.tokens if "%r1%navigate_to_pose%_action%status" in t]
        assert len(status) == 1 and status[0].split("/")[5] == "MP" and status[0].endswith("/:1:,1:,:,:,,")  # transient local
        entities = [t.split("/") for t in edge.tokens if t.split("/")[5] != "NN"]
        kinds = {parts[9]: parts[5] for parts in entities if "pose" in parts[9]}
        assert kinds == {
            "%r1%navigate_to_pose%_action%send_goal": "SS",
            "%r1%navigate_to_pose%_action%cancel_goal": "SS",
            "%r1%navigate_to_pose%_action%get_result": "SS",
            "%r1%navigate_to_pose%_action%feedback": "MP",
            "%r1%navigate_to_pose%_action%status": "MP",
            "%r1%goal_pose": "MS",
            "%r1%initialpose": "MS",
        }
        assert edge.rmf_keys == {}  # no --rmf: no plain keys
    finally:
        edge.close()


@pytest.mark.parametrize(("second", "shares_feedback"), [("kilted", True), ("rolling", False), ("humble", None)])
def test_two_distros_with_one_key_serve_it_once(session: zenoh.Session, second: str, shares_feedback: bool | None) -> None:
    """Jazzy's and Kilted's keys are one (the same definitions, the same hashes): the first node serves them, or every
    goal, command and call was taken twice; Rolling's action feedback is its own; Humble's keys all differ (no
    hashes); an absolute topic (/diagnostics, /parameter_events) is every node's."""
    taken: dict[str, object] = {}
    codec = RosCodec()
    first = Ros2Zenoh(session, Ros2Settings(), codec, distro=Distro.JAZZY, taken=taken)
    other = Ros2Zenoh(session, Ros2Settings(), codec, distro=Distro(second), taken=taken)
    try:
        relative = {t.key_name for t in [*topics(True, robot_model=True), *nav_topics()] if not t.absolute}
        expected = set() if shares_feedback is None else relative | set(first.service_keys)
        if shares_feedback is False:
            expected.discard("navigate_to_pose/_action/feedback")
        assert first._elsewhere == set() and other._elsewhere == expected
        assert {"diagnostics", "parameter_events"}.isdisjoint(other._elsewhere)
        mine = relative | set(first.service_keys)  # each node owns the keys the other does not serve for it
        assert sum(o is first for o in taken.values()) == len(mine) and sum(o is other for o in taken.values()) == len(mine - expected)
    finally:
        first.close()
    assert all(owner is other for owner in taken.values())  # a node closed (to be started again) lets go of its keys
    other.close()
    assert taken == {}
