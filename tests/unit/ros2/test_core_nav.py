"""The core's navigation parts without Zenoh: map -> odom on /tf once placed, free_fleet's <name>/tf with its own
(unprefixed) frames, its battery, RViz's pose tools' bad payloads reported, the action's calls and queries routed."""

from __future__ import annotations

import math
import struct
from typing import Any

import pytest

from blackmetal.robot_model import Encoders
from blackmetal.ros2.core import Ros2Core
from blackmetal.ros2.messages import RosCodec
from blackmetal.ros2.navigate import FEEDBACK, RMF, RMF_BATTERY, RMF_TF, SEND_GOAL, STATUS
from blackmetal.ros2.options import Ros2Options
from blackmetal.ros2.ros_types import TF_MESSAGE, Frames
from blackmetal.ros2.settings import diagonal_matrix
from blackmetal.schemas import ErrorReport, Keys, encode, make_pose
from blackmetal.schemas.navigation import MapPose, NavFeedback, PlanarPose

NOW = 1_700_000_000.0


class Out:
    def __init__(self) -> None:
        self.ros_out: list[tuple[str, bytes]] = []
        self.errors: list[ErrorReport] = []
        self.queries: list[tuple[str, bytes | None, int]] = []
        self.refused: dict[int, str] = {}

    def ros(self, topic: str, data: bytes) -> None:
        self.ros_out.append((topic, data))

    def blackmetal(self, key: str, payload: bytes) -> None:
        pass

    def error(self, message: ErrorReport) -> None:
        self.errors.append(message)

    def service_reply(self, call: int, data: bytes, attachment: bytes | None) -> None:
        pass

    def service_refuse(self, call: int, reason: str) -> None:
        self.refused[call] = reason

    def query(self, key: str, payload: bytes | None, tag: int, timeout: float) -> None:
        self.queries.append((key, payload, tag))

    def follow(self, streams: frozenset[str]) -> None:
        pass

    def topic(self, name: str) -> list[bytes]:
        return [data for topic, data in self.ros_out if topic == name]


@pytest.fixture(scope="module")
def codec() -> RosCodec:
    return RosCodec()


def make(codec: RosCodec, prefix: str = "", rmf: str = "", battery: float | None = None) -> tuple[Ros2Core, Out]:
    out = Out()
    options = Ros2Options(
        frames=Frames(prefix + "odom", prefix + "base_footprint"),
        pose_covariance=diagonal_matrix("0,0,0,0,0,0", "p"),
        twist_covariance=diagonal_matrix("0,0,0,0,0,0", "t"),
        publish_tf=True,
        joint_names=("l", "r"),
        wheel_radius=0.1,
        encoders=Encoders(),
        rmf_name=rmf,
        rmf_battery=battery,
    )
    return Ros2Core(options, Keys("fleet/r1"), out, codec, wallclock=lambda: NOW), out


def frames(codec: RosCodec, data: bytes) -> list[tuple[str, str, float]]:
    return [(t.header.frame_id, t.child_frame_id, t.transform.translation.x) for t in codec.decode(data, TF_MESSAGE).transforms]


def test_map_to_odom_joins_every_tf_once_placed(codec: RosCodec) -> None:
    core, out = make(codec, prefix="r1/", rmf="r1")
    core.start()
    assert out.queries[-1][:2] == ("fleet/r1/nav/map_pose", None)  # asked at the start: it may be running already
    core.on_matched("tf", True, now=1.0)  # someone subscribes to /tf
    pose = encode(make_pose(NOW, 1.0, 0.0, 0.0))
    core.on_pose(pose, now=1.0)
    assert frames(codec, out.topic("tf")[-1]) == [("r1/odom", "r1/base_footprint", 1.0)]
    core.nav.on_map_pose(encode(MapPose(stamp=NOW, x=5.0, y=0.0, yaw=math.pi / 2)), now=1.1)
    core.on_pose(pose, now=1.2)
    assert frames(codec, out.topic("tf")[-1]) == [("map", "r1/odom", 5.0), ("r1/odom", "r1/base_footprint", 1.0)]
    # free_fleet's: the frames as Nav2 names them (it prefixes them with the robot's name itself)
    assert frames(codec, out.topic(RMF_TF)[-1]) == [("map", "odom", 5.0), ("odom", "base_footprint", 1.0)]


def test_one_robots_tf_is_encoded_once_for_both(codec: RosCodec) -> None:
    core, out = make(codec, rmf="robot")
    core.on_pose(encode(make_pose(NOW, 1.0, 0.0, 0.0)), now=1.0)
    assert out.topic("tf") == out.topic(RMF_TF) and out.topic("tf")[0] is out.topic(RMF_TF)[0]


def test_battery_only_when_known(codec: RosCodec) -> None:
    core, out = make(codec, rmf="robot", battery=0.42)
    core.tick(1.0)
    (battery,) = out.topic(RMF_BATTERY)
    assert codec.decode(battery, "sensor_msgs/msg/BatteryState").percentage == pytest.approx(0.42)
    core.tick(1.5)
    assert len(out.topic(RMF_BATTERY)) == 1 and core.next_deadline() <= 2.0
    quiet, out = make(codec, rmf="robot")
    quiet.tick(1.0)
    assert out.topic(RMF_BATTERY) == []


def test_pose_tools_bad_payloads_are_reported(codec: RosCodec) -> None:
    core, out = make(codec)
    core.on_goal_pose(b"\x00\x01\x00\x00" + b"\x00" * 5, now=1.0)
    core.on_initial_pose(b"not cdr", now=1.0)
    assert [e.key for e in out.errors] == ["goal_pose", "initialpose"]
    assert out.queries == []
    stamped = codec.encode(
        "geometry_msgs/msg/PoseStamped",
        header=codec.header(NOW, "map"),
        pose=codec.message(
            "geometry_msgs/msg/Pose",
            position=codec.message("geometry_msgs/msg/Point", x=1.0, y=2.0, z=0.0),
            orientation=codec.message("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0),
        ),
    )
    core.on_goal_pose(stamped, now=2.0)
    assert out.queries[-1][0] == "fleet/r1/nav/goal"


def test_calls_reach_the_action_and_bad_attachments_are_refused(codec: RosCodec) -> None:
    core, out = make(codec, rmf="robot")
    goal: Any = (
        b"\x00\x01\x00\x00" + bytes(16) + struct.pack("<iII", 0, 0, 1) + b"\x00" + bytes(3) + struct.pack("<7d", 1, 2, 0, 0, 0, 0, 1)
    )
    goal += struct.pack("<I", 1) + b"\x00"
    core.on_service_request(SEND_GOAL, 1, goal, None, now=1.0)
    core.on_service_request(RMF + SEND_GOAL, 2, goal, None, now=1.0)
    assert [q[0] for q in out.queries] == ["fleet/r1/nav/goal"] * 2 and all(q[2] < 0 for q in out.queries)
    core.on_service_request(SEND_GOAL, 4, b"\x00\x01\x00\x00", None, now=1.0)  # a bad request: counted as a rejected input
    assert core.stats.bad_inputs.total == 1 and out.errors[-1].key == SEND_GOAL
    core.on_service_request(SEND_GOAL, 3, goal, b"\x01\x02", now=1.0)
    assert "not rmw_zenoh's" in out.refused[3] and len(out.queries) == 2
    core.on_query_done(out.queries[0][2], now=3.0)  # negative tags are the action's
    assert "no navigation service answered" in out.errors[-1].reason


def test_feedback_is_encoded_only_while_someone_subscribes(codec: RosCodec) -> None:
    core, out = make(codec, rmf="robot")
    core.start()  # from now on only what is watched
    pose = PlanarPose(x=0.5, y=1.0, yaw=0.25)
    running = encode(
        NavFeedback(stamp=NOW, goal_id="ab" * 16, state="executing", pose=pose, goal=pose, distance_remaining=1.0, eta=2.0, elapsed=1.0)  # type: ignore[arg-type]
    )
    core.nav.on_feedback(running, now=1.0)
    assert out.topic(FEEDBACK) == out.topic(RMF + FEEDBACK) == [] and len(out.topic(STATUS)) == 1  # the status always
    core.on_matched(RMF + FEEDBACK, True, now=1.1)  # free_fleet subscribes
    core.nav.on_feedback(running, now=1.2)
    assert out.topic(FEEDBACK) == [] and len(out.topic(RMF + FEEDBACK)) == 1
    core.on_matched(FEEDBACK, True, now=1.3)  # and a ROS action client
    core.nav.on_feedback(running, now=1.4)
    assert len(out.topic(FEEDBACK)) == 1 and len(out.topic(RMF + FEEDBACK)) == 2


def test_the_navigations_liveliness_reaches_the_action(codec: RosCodec) -> None:
    core, out = make(codec)
    core.on_alive("nav", True, now=1.0)
    assert out.queries[-1][0] == "fleet/r1/nav/map_pose"
