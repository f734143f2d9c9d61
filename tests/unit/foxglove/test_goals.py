"""The 3D panel's publish tools read as navigation requests, and the service's answers shown (pure, on a fake clock)."""

from __future__ import annotations

import json
import math
from typing import Any

import pytest

from blackmetal.foxglove.goals import MAX_WAITING, NavDesk, NavRequest, Quaternion, nav_frame, request, robot_of_frame, yaw_of
from blackmetal.foxglove.naming import NavTopic, StatusLevel
from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import (
    ErrorReport,
    Keys,
    MapPose,
    NavCancelReply,
    NavGoal,
    NavGoalReply,
    PayloadError,
    Pose,
    SetPose,
    decode,
    encode,
)

KEYS = Keys("robot")


def pose_stamped(x: float, y: float, yaw: float, frame: str = "map", **more: Any) -> bytes:
    """What Foxglove's "Publish pose" sends (its header's stamp as ROS 1 has it; ROS 2's nanosec is taken alike)."""
    header = {"stamp": {"sec": 1700000000, "nsec": 5}, "frame_id": frame}
    orientation = {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}
    return json.dumps({"header": header, "pose": {"position": {"x": x, "y": y, "z": 0.0}, "orientation": orientation}, **more}).encode()


def pose_estimate(x: float, y: float, yaw: float, frame: str = "map") -> bytes:
    stamped = json.loads(pose_stamped(x, y, yaw, frame))
    stamped["pose"] = {"covariance": [0.0] * 36, "pose": stamped["pose"]}
    return json.dumps(stamped).encode()


def test_a_goal_pose_becomes_a_nav_goal_with_its_frame_and_heading() -> None:
    for topic in (NavTopic.GOAL_POSE, NavTopic.MOVE_BASE_GOAL):
        asked = request(topic, pose_stamped(1.5, -2.0, math.pi / 2, "odom"), KEYS)
        assert isinstance(asked, NavRequest) and asked.key == "robot/nav/goal"
        goal = decode(NavGoal, asked.payload)
        assert (goal.x, goal.y, goal.frame) == (1.5, -2.0, "odom") and goal.yaw == pytest.approx(math.pi / 2)
        assert asked.summary == "goal (1.50, -2.00) facing 90 deg in odom"
    goal = decode(NavGoal, request(NavTopic.GOAL_POSE, pose_stamped(1.0, 2.0, -3.0, "/map"), KEYS).payload)  # type: ignore[union-attr]
    assert goal.frame == "map" and goal.yaw == pytest.approx(-3.0), "ROS 1's leading slash is taken"
    ros2 = json.dumps({"header": {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": ""}, "pose": {"position": {"x": 3.0}}}).encode()
    goal = decode(NavGoal, request(NavTopic.GOAL_POSE, ros2, KEYS).payload)  # type: ignore[union-attr]
    assert (goal.x, goal.y, goal.yaw, goal.frame) == (3.0, 0.0, 0.0, "map"), "no frame: the map; no orientation: facing x"


def test_a_pose_estimate_becomes_a_set_pose_and_a_clicked_point_a_line_for_the_log() -> None:
    asked = request(NavTopic.INITIAL_POSE, pose_estimate(4.0, 5.0, math.pi), KEYS)
    assert isinstance(asked, NavRequest) and asked.key == "robot/nav/set_pose"
    placed = decode(SetPose, asked.payload)
    assert (placed.x, placed.y, placed.frame) == (4.0, 5.0, "map") and abs(placed.yaw) == pytest.approx(math.pi)
    point = json.dumps({"header": {"frame_id": "map"}, "point": {"x": 1.0, "y": 2.0, "z": 0.0}}).encode()
    assert request(NavTopic.CLICKED_POINT, point, KEYS) == "clicked point (1.00, 2.00, 0.00) in map"


def test_yaw_from_any_non_zero_quaternion() -> None:
    for yaw in (0.0, 0.3, -1.2, math.pi - 1e-6):
        q = Quaternion(z=math.sin(yaw / 2), w=math.cos(yaw / 2))
        assert yaw_of(q) == pytest.approx(yaw)
        assert yaw_of(Quaternion(z=3 * q.z, w=3 * q.w)) == pytest.approx(yaw), "not unit length: same heading"
    with pytest.raises(PayloadError, match="not a rotation"):
        yaw_of(Quaternion(w=0.0))


def test_frames_map_odom_and_the_robots_own_and_a_fleets_robots() -> None:
    assert [nav_frame(f) for f in ("map", "/map", "", "odom", "/odom", "site2")] == ["map", "map", "map", "odom", "odom", "site2"]
    assert nav_frame("r3/odom", "r3/") == "odom" and nav_frame("odom", "r3/") == "odom" and nav_frame("map", "r3/") == "map"
    for frame, prefix, words in (
        ("base_link", "", "set the panel's display frame to map or odom"),
        ("r3/base_footprint", "r3/", "map or r3/odom"),
        ("r2/odom", "r3/", "not this robot's"),
        ("r3/left_wheel", "r3/", "not this robot's"),
    ):
        with pytest.raises(PayloadError, match=words):
            nav_frame(frame, prefix)
    assert robot_of_frame("r3/odom", ("r1", "r3")) == "r3" and robot_of_frame("/r1/base_link", ("r1",)) == "r1"
    assert robot_of_frame("map", ("r1",)) is None and robot_of_frame("r9/odom", ("r1",)) is None


@pytest.mark.parametrize(
    ("topic", "payload", "error", "words"),
    [
        (NavTopic.GOAL_POSE, b"{not json", PayloadError, "not valid JSON"),
        (NavTopic.GOAL_POSE, b'{"header": {}}', PayloadError, "pose"),
        (NavTopic.GOAL_POSE, pose_stamped(1.0, 2.0, 0.0, extra=1), PayloadError, "extra"),
        (NavTopic.GOAL_POSE, b'{"pose": {"positon": {"x": 1}}}', PayloadError, "positon"),
        (NavTopic.GOAL_POSE, b'{"pose": {"position": {"x": "1"}}}', PayloadError, "Expected `float`"),
        (NavTopic.GOAL_POSE, b'{"pose": {"position": {"x": 1e999}}}', PayloadError, "not finite"),
        (NavTopic.GOAL_POSE, b'{"pose": {"orientation": {"w": 0}}}', PayloadError, "not a rotation"),
        (NavTopic.INITIAL_POSE, pose_estimate(1.0, 2.0, 0.0, "base_link"), PayloadError, "display frame"),
        (NavTopic.GOAL_POSE, pose_stamped(1.0, 2.0, 0.0, "r2/odom"), PayloadError, "not this robot's"),
        (NavTopic.INITIAL_POSE, pose_stamped(1.0, 2.0, 0.0), PayloadError, "PoseWithCovarianceStamped"),
        (NavTopic.CLICKED_POINT, b'{"point": {"x": 1e999}}', PayloadError, "not finite"),
        (NavTopic.CLICKED_POINT, b"[]", PayloadError, "JSON object"),
        (NavTopic.GOAL_POSE, pose_stamped(1.0, 2.0, 0.0, "m" * 65), PayloadError, "length <= 64"),
    ],
)
def test_bad_messages_are_refused_with_a_sentence(topic: NavTopic, payload: bytes, error: type[Exception], words: str) -> None:
    with pytest.raises(error, match=words):
        request(topic, payload, KEYS)


def test_a_goal_from_the_robots_own_frame_is_placed_in_odom_from_the_odometrys_pose() -> None:
    d = Desk()
    d.desk.on_message(5, "/goal_pose", NavTopic.GOAL_POSE, pose_stamped(1.0, 0.0, math.pi / 2, "base_link"), now=0.0)
    ((key, call, payload),) = d.asked
    assert (key, payload) == (KEYS.pose, b""), "the odometry's pose, asked for"
    robot = Pose(stamp=1.0, x=2.0, y=3.0, yaw=math.pi / 2)
    d.desk.on_reply(call, encode(robot), None, now=0.1)
    d.desk.on_reply(call, None, None, now=0.1)  # the pose query's end: the goal's own query waits on
    key, call, payload = d.asked[-1]
    goal = decode(NavGoal, payload)
    assert (
        key == KEYS.nav_goal
        and goal.frame == "odom"
        and (goal.x, goal.y) == pytest.approx((2.0, 4.0))
        and goal.yaw == pytest.approx(math.pi)
    )
    d.desk.on_reply(call, encode(NavGoalReply(accepted=True, goal_id="cd" * 16)), None, now=0.2)
    assert (
        d.shown[-1][1]
        == f"goal (1.00, 0.00) facing 90 deg from the robot (base_link), at (2.00, 4.00) facing 180 deg in odom: accepted as {'cd' * 16}"
    )

    d.desk.on_message(5, "/goal_pose", NavTopic.GOAL_POSE, pose_stamped(1.0, 0.0, 0.0, "base_footprint"), now=1.0)
    d.desk.on_reply(d.asked[-1][1], None, None, now=1.1)
    assert "no odometry answered on robot/pose: is blackmetal odometry running on prefix 'robot'?" in d.shown[-1][1]
    d.desk.on_message(5, "/goal_pose", NavTopic.GOAL_POSE, pose_stamped(1.0, 0.0, 0.0, "base_link"), now=2.0)
    d.desk.on_reply(d.asked[-1][1], b"not a pose", None, now=2.1)
    assert "the robot's pose for the goal (1.00, 0.00) facing 0 deg from the robot (base_link) did not come" in d.shown[-1][1]
    assert d.asked[-1][0] == KEYS.pose, "no goal without the pose"


class Desk:
    """A NavDesk and everything it sends, by kind."""

    def __init__(self) -> None:
        self.statuses: list[tuple[int | None, StatusLevel, str]] = []
        self.errors: list[ErrorReport] = []
        self.refusals: list[tuple[int, str, str]] = []
        self.asked: list[tuple[str, int, bytes]] = []
        self.answers: dict[int, tuple[bytes | None, str | None]] = {}
        self.shown: list[tuple[StatusLevel, str]] = []
        reporter = ErrorReporter("foxglove", self.errors.append, lambda: 1000.0)
        self.desk = NavDesk(KEYS, self, reporter, self.refuse, lambda *asked: self.asked.append(asked), 2.0)  # type: ignore[arg-type]
        self.desk.show = lambda level, message: self.shown.append((level, message))

    def status(self, client: int | None, level: StatusLevel, message: str) -> None:
        self.statuses.append((client, level, message))

    def answer(self, call: int, response: bytes | None, failure: str | None) -> None:
        self.answers[call] = (response, failure)

    def refuse(self, client: int, topic: str, reason: str, text: str, now: float) -> None:
        self.refusals.append((client, topic, reason))


def test_a_goal_accepted_and_one_rejected_are_shown_with_the_services_reason() -> None:
    d = Desk()
    d.desk.on_message(4, "/goal_pose", NavTopic.GOAL_POSE, pose_stamped(1.0, 2.0, 0.0), now=0.0)
    ((key, call, payload),) = d.asked
    assert key == KEYS.nav_goal and decode(NavGoal, payload).x == 1.0 and d.desk.next_deadline() == 2.0
    d.desk.on_reply(call, encode(NavGoalReply(accepted=True, goal_id="ab" * 16)), None, now=0.01)
    d.desk.on_reply(call, None, None, now=0.02)  # the query's end, after its answer: nothing more
    assert d.shown == [(StatusLevel.INFO, f"goal (1.00, 2.00) facing 0 deg in map: accepted as {'ab' * 16}")]
    assert not d.statuses and not d.errors and d.desk.next_deadline() == math.inf

    d.desk.on_message(4, "/goal_pose", NavTopic.GOAL_POSE, pose_stamped(9.0, 0.0, 0.0), now=1.0)
    reason = "the robot's e-stop is engaged: release it first"
    d.desk.on_reply(d.asked[-1][1], encode(NavGoalReply(accepted=False, reason=reason)), None, now=1.01)
    assert d.shown[-1][0] is StatusLevel.WARNING and reason in d.shown[-1][1] and "rejected the goal (9.00, 0.00)" in d.shown[-1][1]
    assert d.statuses == [(4, StatusLevel.WARNING, d.shown[-1][1])], "told to the client that sent it"
    assert not d.errors, "a rejection is the service's to report"


def test_a_set_pose_answer_an_error_reply_no_service_and_a_late_service() -> None:
    d = Desk()
    d.desk.on_message(1, "/initialpose", NavTopic.INITIAL_POSE, pose_estimate(1.0, 1.0, 0.0), now=0.0)
    d.desk.on_reply(d.asked[-1][1], encode(MapPose(stamp=1.0, x=0.5, y=0.5, yaw=0.0, by="/initialpose")), None, now=0.1)
    assert d.shown[-1] == (StatusLevel.INFO, "pose estimate (1.00, 1.00) facing 0 deg in map: taken, map -> odom now (0.50, 0.50) at 0 deg")

    d.desk.on_message(1, "/goal_pose", NavTopic.GOAL_POSE, pose_stamped(1.0, 2.0, 0.0), now=1.0)
    d.desk.on_reply(d.asked[-1][1], None, b"busy", now=1.1)
    assert "refused the goal (1.00, 2.00) facing 0 deg in map: busy" in d.shown[-1][1]

    d.desk.on_message(1, "/goal_pose", NavTopic.GOAL_POSE, pose_stamped(1.0, 2.0, 0.0), now=2.0)
    d.desk.on_reply(d.asked[-1][1], None, None, now=2.1)
    assert "no navigation service answered on robot/nav/goal: is blackmetal nav running on prefix 'robot'?" in d.shown[-1][1]
    assert d.statuses[-1][1] is StatusLevel.ERROR and [e.key for e in d.errors] == ["foxglove:/goal_pose"]

    d.desk.on_message(1, "/goal_pose", NavTopic.GOAL_POSE, pose_stamped(1.0, 2.0, 0.0), now=3.0)
    d.desk.tick(4.9)
    assert d.desk.calls, "not due yet"
    d.desk.tick(5.0)
    assert not d.desk.calls and "did not answer within 2 s" in d.shown[-1][1]


def test_a_bad_message_is_refused_and_nothing_is_asked_and_a_point_is_only_shown() -> None:
    d = Desk()
    d.desk.on_message(2, "/goal_pose", NavTopic.GOAL_POSE, b'{"pose": {"position": {"x": 1e999}}}', now=0.0)
    d.desk.on_message(2, "/goal_pose", NavTopic.GOAL_POSE, b"nope", now=0.0)
    assert [r[2].endswith("nothing was sent to the navigation service") for r in d.refusals] == [True, True]
    d.desk.on_message(2, "/clicked_point", NavTopic.CLICKED_POINT, b'{"header": {"frame_id": "odom"}, "point": {"x": 1}}', now=0.0)
    assert not d.asked and d.shown == [(StatusLevel.INFO, "clicked point (1.00, 0.00, 0.00) in odom")]
    for i in range(100):  # a script's flood of points within a second: ten lines
        d.desk.on_message(2, "/clicked_point", NavTopic.CLICKED_POINT, b'{"point": {"x": 2}}', now=1.0 + i * 0.01)
    assert len(d.shown) == 1 + 10


def test_a_flood_of_goals_is_bounded_by_the_answers_waited_for() -> None:
    d = Desk()
    for i in range(MAX_WAITING + 5):
        d.desk.on_message(3, "/goal_pose", NavTopic.GOAL_POSE, pose_stamped(float(i), 0.0, 0.0), now=i * 0.001)
    assert len(d.asked) == MAX_WAITING and len(d.refusals) == 5 and "already wait for the navigation service's answer" in d.refusals[0][2]
    d.desk.on_reply(d.asked[0][1], encode(NavGoalReply(accepted=True, goal_id="ef" * 16)), None, now=0.1)
    d.desk.on_message(3, "/goal_pose", NavTopic.GOAL_POSE, pose_stamped(1.0, 0.0, 0.0), now=0.2)
    assert len(d.asked) == MAX_WAITING + 1, "one answered: one more may go"


def test_cancel_goal_asks_nav_cancel_and_answers_the_call_with_what_it_ended() -> None:
    d = Desk()
    d.desk.cancel(31, 2, "cancel_goal", now=0.0)
    ((key, call, payload),) = d.asked
    assert key == KEYS.nav_cancel and json.loads(payload) == {"goal_id": None}, "whatever goal runs"
    d.desk.on_reply(call, encode(NavCancelReply(canceled=["ab" * 16])), None, now=0.1)
    assert json.loads(d.answers[31][0] or b"") == {"success": True, "message": f"canceled {'ab' * 16}"}
    assert d.shown[-1] == (StatusLevel.INFO, f"cancel of the running goal: canceled {'ab' * 16}")
    d.desk.cancel(32, 2, "cancel_goal", now=1.0)
    d.desk.on_reply(d.asked[-1][1], encode(NavCancelReply(reason="no goal runs")), None, now=1.1)
    assert json.loads(d.answers[32][0] or b"") == {"success": False, "message": "nothing canceled: no goal runs"}
    d.desk.cancel(33, 2, "cancel_goal", now=2.0)
    d.desk.tick(4.0)
    failure = d.answers[33][1] or ""
    assert d.answers[33][0] is None and "did not answer within 2 s on robot/nav/cancel" in failure and "blackmetal nav" in failure
    assert not d.statuses, "a call's failure is its answer, not a status"
    assert [e.key for e in d.errors] == ["foxglove:cancel_goal"]


def test_the_answer_to_a_client_that_left_is_shown_and_sent_to_nobody() -> None:
    d = Desk()
    d.desk.on_message(7, "/goal_pose", NavTopic.GOAL_POSE, pose_stamped(1.0, 2.0, 0.0), now=0.0)
    d.desk.client_gone(7)
    d.desk.on_reply(d.asked[-1][1], encode(NavGoalReply(accepted=False, reason="e-stop")), None, now=0.1)
    assert not d.statuses and d.shown[-1][0] is StatusLevel.WARNING, "a status for a client not known goes to every client"
    d.desk.on_message(7, "/goal_pose", NavTopic.GOAL_POSE, pose_stamped(1.0, 2.0, 0.0), now=1.0)
    d.desk.client_gone(7)
    d.desk.tick(3.0)
    assert not d.statuses and [e.key for e in d.errors] == ["foxglove:/goal_pose"], "reported all the same"
    assert d.errors[0].reason.startswith("a client that left: the navigation service did not answer within 2 s")
