"""The navigate_to_pose action translated to the robot's nav/* keys, without Zenoh: calls in as CDR, the queries the
adapter asks and the answers it gets, the replies, feedback and status out."""

from __future__ import annotations

import json
import math
import struct
from typing import Any

import pytest

from blackmetal.ros2 import action_cdr as cdr
from blackmetal.ros2.action_types import NavLayout
from blackmetal.ros2.naming import parse_attachment
from blackmetal.ros2.navigate import (
    CANCEL_GOAL,
    FEEDBACK,
    GET_RESULT,
    MAX_ASKING,
    MAX_GOALS,
    MAX_WAITING,
    RESULT_POLL_S,
    RMF,
    SEND_GOAL,
    STATUS,
    NavAction,
)
from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import ErrorReport, Keys, encode
from blackmetal.schemas.navigation import MapPose, NavCancelReply, NavFeedback, NavGoalReply, NavResult, PlanarPose

UUID = bytes(range(1, 17))
HEX = UUID.hex()
H = b"\x00\x01\x00\x00"
NOW = 1_700_000_000.0
GID = bytes(range(16, 32))


class Out:
    def __init__(self) -> None:
        self.ros_out: list[tuple[str, bytes]] = []
        self.replies: dict[int, tuple[bytes, bytes | None]] = {}
        self.refused: dict[int, str] = {}
        self.queries: list[tuple[str, Any, int]] = []
        self.errors: list[ErrorReport] = []

    def ros(self, topic: str, data: bytes) -> None:
        self.ros_out.append((topic, data))

    def blackmetal(self, key: str, payload: bytes) -> None:
        raise AssertionError("the action never drives")

    def error(self, message: ErrorReport) -> None:
        self.errors.append(message)

    def service_reply(self, call: int, data: bytes, attachment: bytes | None) -> None:
        self.replies[call] = (data, attachment)

    def service_refuse(self, call: int, reason: str) -> None:
        self.refused[call] = reason

    def query(self, key: str, payload: bytes | None, tag: int, timeout: float) -> None:
        self.queries.append((key, None if payload is None else json.loads(payload), tag))

    def follow(self, streams: frozenset[str]) -> None:
        pass

    def topic(self, name: str) -> list[bytes]:
        return [data for topic, data in self.ros_out if topic == name]


def make(layout: NavLayout = NavLayout.JAZZY, rmf: bool = False) -> tuple[NavAction, Out]:
    out = Out()
    reporter = ErrorReporter("ros2", out.error, lambda: NOW)
    return NavAction(
        Keys("fleet/r1"), out, reporter, lambda: NOW, layout, "r1/odom", rmf=rmf, battery=(lambda: b"battery") if rmf else None
    ), out


def send_goal_payload(frame: str = "map", x: float = 1.0, y: float = 2.0, yaw: float = 0.5, uuid: bytes = UUID) -> bytes:
    q = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    data = frame.encode() + b"\x00"
    body = uuid + struct.pack("<iII", 0, 0, len(data)) + data
    body += b"\x00" * (-len(body) % 8) + struct.pack("<7d", x, y, 0.0, *q) + struct.pack("<I", 1) + b"\x00"
    return H + body


def status_list(data: bytes) -> list[tuple[bytes, int]]:
    count = struct.unpack_from("<I", data, 4)[0]
    out, offset = [], 8
    for _ in range(count):
        offset += -(offset - 4) % 4
        uuid = data[offset : offset + 16]
        out.append((uuid, data[offset + 24]))
        offset += 25
    return out


def feedback(state: str, reason: str = "", goal_id: str = HEX) -> bytes:
    pose = PlanarPose(x=0.5, y=1.0, yaw=0.25, frame="map")
    return encode(
        NavFeedback(
            stamp=NOW,
            goal_id=goal_id,
            state=state,
            pose=pose,
            goal=pose,
            distance_remaining=1.5,
            eta=3.0,
            elapsed=2.0,
            reason=reason,  # type: ignore[arg-type]
        )
    )


def accept(nav: NavAction, out: Out, call: int = 1, attachment: tuple[int, bytes] | None = None) -> None:
    nav.on_request(SEND_GOAL, call, send_goal_payload(), attachment, now=1.0)
    key, asked, tag = out.queries[-1]
    assert key == "fleet/r1/nav/goal"
    nav.on_query_reply(tag, True, encode(NavGoalReply(accepted=True, goal_id=asked["goal_id"])), now=1.01)


def test_send_goal_becomes_nav_goal_and_its_reply_the_response() -> None:
    nav, out = make()
    nav.on_request(SEND_GOAL, 1, send_goal_payload(yaw=0.5), (7, GID), now=1.0)
    key, asked, tag = out.queries[-1]
    assert key == "fleet/r1/nav/goal" and tag < 0
    assert asked["goal_id"] == HEX and asked["frame"] == "map" and (asked["x"], asked["y"]) == (1.0, 2.0)
    assert asked["yaw"] == pytest.approx(0.5)
    nav.on_query_reply(tag, True, encode(NavGoalReply(accepted=True, goal_id=HEX)), now=1.01)
    response, attachment = out.replies[1]
    assert response[4] == 1 and struct.unpack_from("<iI", response, 8) == (int(NOW), 0)
    assert attachment is not None and parse_attachment(attachment)[0] == 7 and parse_attachment(attachment)[2] == GID
    assert status_list(out.topic(STATUS)[-1]) == [(UUID, 1)]  # ACCEPTED


def test_a_goal_in_the_odometry_frame_and_frames_refused() -> None:
    nav, out = make()
    for frame in ("r1/odom", "odom"):
        nav.on_request(SEND_GOAL, 1, send_goal_payload(frame=frame), None, now=1.0)
        assert out.queries[-1][1]["frame"] == "odom"
    nav.on_request(SEND_GOAL, 2, send_goal_payload(frame=""), None, now=1.0)
    assert out.queries[-1][1]["frame"] == "map"
    asked = len(out.queries)
    nav.on_request(SEND_GOAL, 3, send_goal_payload(frame="r1/base_footprint"), None, now=1.0)
    assert len(out.queries) == asked and out.replies[3][0][4] == 0  # refused, never asked
    assert "r1/base_footprint" in out.errors[-1].reason


def test_rejections_and_silence_are_refusals_with_the_reason_reported() -> None:
    nav, out = make()
    nav.on_request(SEND_GOAL, 1, send_goal_payload(), None, now=1.0)
    nav.on_query_reply(out.queries[-1][2], True, encode(NavGoalReply(accepted=False, reason="the robot is e-stopped")), now=1.0)
    assert out.replies[1][0][4] == 0 and out.errors == []  # its sentence: the navigation service reports it
    nav.on_request(SEND_GOAL, 2, send_goal_payload(), None, now=1.0)
    nav.on_query_done(out.queries[-1][2], now=3.0)
    assert out.replies[2][0][4] == 0 and "no navigation service answered" in out.errors[-1].reason
    # a request that does not read, or carries a NaN, is answered all the same: rmw_zenoh's client drops error replies
    nav.on_request(SEND_GOAL, 3, b"\x00\x01\x00\x00garbage", None, now=4.0)
    nav.on_request(SEND_GOAL, 4, send_goal_payload(x=math.nan), (9, GID), now=4.0)
    nav.on_request(CANCEL_GOAL, 5, b"", None, now=4.0)
    nav.on_request(GET_RESULT, 6, H + b"\x01", None, now=4.0)
    assert out.replies[3][0][4] == out.replies[4][0][4] == 0 and parse_attachment(out.replies[4][1] or b"")[0] == 9
    assert out.replies[5][0] == cdr.cancel_goal_response(1, []) and out.replies[6][0] == cdr.get_result_response(NavLayout.JAZZY, 0)
    assert "finite" in out.errors[-3].reason and out.refused == {}
    assert out.topic(STATUS) == []  # nothing was accepted


def test_feedback_status_and_a_result_held_until_the_goal_ends() -> None:
    nav, out = make()
    accept(nav, out)
    nav.on_request(GET_RESULT, 2, H + UUID, (3, GID), now=1.1)
    assert 2 not in out.replies  # held open, as rcl_action holds it
    nav.on_feedback(feedback("executing"), now=1.2)
    message = out.topic(FEEDBACK)[-1]
    assert message[4:20] == UUID and status_list(out.topic(STATUS)[-1]) == [(UUID, 2)]
    assert message == cdr.feedback_message(NavLayout.JAZZY, UUID, cdr.Feedback(int(NOW), 0, "map", 0.5, 1.0, 0.25, 2.0, 3.0, 0, 1.5))
    nav.on_feedback(feedback("succeeded"), now=2.0)
    assert len(out.topic(FEEDBACK)) == 1  # a finished goal gets no feedback, its status says
    assert status_list(out.topic(STATUS)[-1]) == [(UUID, 4)]
    response, attachment = out.replies[2]
    assert response == cdr.get_result_response(NavLayout.JAZZY, 4) and attachment is not None and parse_attachment(attachment)[0] == 3
    nav.on_request(GET_RESULT, 3, H + UUID, None, now=2.1)  # asked again: at once
    assert out.replies[3][0] == response


def test_an_aborted_goal_carries_its_reason_and_humble_an_empty_result() -> None:
    for layout in (NavLayout.JAZZY, NavLayout.HUMBLE):
        nav, out = make(layout)
        accept(nav, out)
        nav.on_feedback(feedback("aborted", "e-stop engaged"), now=2.0)
        nav.on_request(GET_RESULT, 2, H + UUID, None, now=2.1)
        assert out.replies[2][0] == cdr.get_result_response(layout, 6, 9000, "e-stop engaged")


def test_a_result_of_a_goal_the_adapter_never_saw_is_asked_of_the_service() -> None:
    nav, out = make()
    nav.on_request(GET_RESULT, 1, H + UUID, None, now=1.0)
    key, asked, tag = out.queries[-1]
    assert key == "fleet/r1/nav/result" and asked == {"goal_id": HEX}
    nav.on_query_reply(tag, True, encode(NavResult(found=False)), now=1.0)
    assert out.replies[1][0] == cdr.get_result_response(NavLayout.JAZZY, 0)  # UNKNOWN
    nav.on_request(GET_RESULT, 2, H + UUID, None, now=1.0)
    nav.on_query_reply(out.queries[-1][2], True, encode(NavResult(found=True, goal_id=HEX, state="executing")), now=1.0)  # type: ignore[arg-type]
    assert 2 not in out.replies
    nav.tick(1.0 + RESULT_POLL_S)  # the safety net: asked again while it waits
    key, asked, tag = out.queries[-1]
    assert key == "fleet/r1/nav/result" and asked == {"goal_id": HEX}
    nav.on_query_reply(tag, True, encode(NavResult(found=True, goal_id=HEX, state="canceled", reason="preempted")), now=2.0)  # type: ignore[arg-type]
    assert out.replies[2][0] == cdr.get_result_response(NavLayout.JAZZY, 5, 0, "preempted")
    assert nav.next_deadline() > 1e9 or nav.results == {}


def test_cancel_all_one_unknown_and_finished() -> None:
    nav, out = make()
    accept(nav, out)
    nav.on_request(CANCEL_GOAL, 2, H + bytes(16) + bytes(8), None, now=2.0)
    key, asked, tag = out.queries[-1]
    assert key == "fleet/r1/nav/cancel" and asked == {"goal_id": None}  # zero id and stamp: whatever runs
    nav.on_query_reply(tag, True, encode(NavCancelReply(canceled=[HEX])), now=2.0)
    assert out.replies[2][0] == cdr.cancel_goal_response(0, [(UUID, int(NOW), 0)])
    assert status_list(out.topic(STATUS)[-1]) == [(UUID, 3)]  # CANCELING until the service says it ended
    nav.on_feedback(feedback("executing"), now=2.05)
    assert status_list(out.topic(STATUS)[-1]) == [(UUID, 3)]
    nav.on_feedback(feedback("canceled"), now=2.1)
    assert status_list(out.topic(STATUS)[-1]) == [(UUID, 5)]
    nav.on_request(CANCEL_GOAL, 5, H + bytes(24), None, now=3.0)
    nav.on_query_reply(out.queries[-1][2], True, encode(NavCancelReply(canceled=["zz" * 16, "1234"])), now=3.0)
    assert out.replies[5][0] == cdr.cancel_goal_response(0, [(bytes(16), 0, 0)] * 2)  # ids not UUIDs: named zero
    other = bytes(16 * [0xAB])
    for call, uuid, code in ((3, other, 2), (4, UUID, 3)):
        nav.on_request(CANCEL_GOAL, call, H + uuid + bytes(8), None, now=3.0)
        assert out.queries[-1][1] == {"goal_id": uuid.hex()}
        nav.on_query_reply(out.queries[-1][2], True, encode(NavCancelReply(canceled=[], reason="no such goal")), now=3.0)
        assert out.replies[call][0] == cdr.cancel_goal_response(code, [])


def test_free_fleets_surface_answers_results_at_once_and_publishes_its_own() -> None:
    nav, out = make(rmf=True)
    nav.on_request(RMF + SEND_GOAL, 1, send_goal_payload(), None, now=1.0)
    nav.on_query_reply(out.queries[-1][2], True, encode(NavGoalReply(accepted=True, goal_id=HEX)), now=1.0)
    assert out.replies[1] == (cdr.send_goal_response(True, int(NOW), 0), None)  # no attachment on plain keys
    nav.on_feedback(feedback("executing"), now=1.5)
    assert out.topic(RMF + FEEDBACK) == out.topic(FEEDBACK) and out.topic(RMF + STATUS) == out.topic(STATUS)
    nav.on_request(RMF + GET_RESULT, 2, H + UUID, None, now=1.6)
    assert out.replies[2][0] == cdr.get_result_response(NavLayout.JAZZY, 2)  # EXECUTING: free_fleet asks again
    nav.tick(2.0)
    assert out.topic(RMF + "battery_state") == [b"battery"]


def test_rviz_tools_and_the_map_frame() -> None:
    nav, out = make()
    nav.on_goal_pose(cdr.StampedPose(0, 0, "map", 3.0, 4.0, None), now=1.0)
    key, asked, tag = out.queries[-1]
    assert key == "fleet/r1/nav/goal" and asked == {"x": 3.0, "y": 4.0, "yaw": None, "frame": "map", "goal_id": None}
    nav.on_query_reply(tag, True, encode(NavGoalReply(accepted=False, reason="outside the geofence")), now=1.0)
    assert out.errors == [] and out.replies == {}  # the navigation service reports its refusal
    assert nav.map_transform("r1/odom") is None
    nav.on_initial_pose(cdr.StampedPose(0, 0, "map", 1.0, 2.0, math.pi / 2), now=2.0)
    key, asked, tag = out.queries[-1]
    assert key == "fleet/r1/nav/set_pose" and asked["x"] == 1.0 and asked["yaw"] == pytest.approx(math.pi / 2)
    nav.on_query_reply(tag, True, encode(MapPose(stamp=NOW, x=0.5, y=0.0, yaw=math.pi, by="initialpose")), now=2.0)
    placed = nav.map_transform("r1/odom")
    assert placed is not None and (placed.parent, placed.child, placed.translation) == ("map", "r1/odom", (0.5, 0.0, 0.0))
    assert placed.rotation[2] == pytest.approx(1.0)
    nav.on_map_pose(encode(MapPose(stamp=NOW, x=-1.0, y=0.0, yaw=0.0)), now=3.0)
    assert nav.map_transform("r1/odom").translation == (-1.0, 0.0, 0.0)  # type: ignore[union-attr]
    nav.on_initial_pose(cdr.StampedPose(0, 0, "r1/odom", 1.0, 2.0, None), now=4.0)
    assert "on the map" in out.errors[-1].reason
    nav.on_map_pose(b"{}", now=5.0)
    assert "MapPose" in out.errors[-1].reason or "map_pose" in out.errors[-1].key


def test_feedback_of_goals_from_other_clients_and_bad_feedback() -> None:
    nav, out = make()
    other = "ab" * 16
    nav.on_feedback(feedback("executing", goal_id=other), now=1.0)
    assert status_list(out.topic(STATUS)[-1]) == [(bytes.fromhex(other), 2)]
    nav.on_feedback(b'{"goal_id": 3}', now=1.0)
    assert out.errors and "feedback" in out.errors[-1].reason
    for i in range(40):  # the memory is bounded
        nav.on_feedback(feedback("succeeded", goal_id=f"{i:032x}"), now=2.0)
    assert len(status_list(out.topic(STATUS)[-1])) == 32


def test_a_preempted_goal_is_asked_after_and_a_forgotten_one_ends_unknown() -> None:
    nav, out = make()
    accept(nav, out)
    nav.on_feedback(feedback("executing"), now=1.5)
    nav.on_request(GET_RESULT, 5, H + UUID, None, now=1.6)
    second = bytes(16 * [0xCD])
    nav.on_request(SEND_GOAL, 2, send_goal_payload(uuid=second), None, now=2.0)
    nav.on_query_reply(out.queries[-1][2], True, encode(NavGoalReply(accepted=True, goal_id=second.hex())), now=2.0)
    nav.tick(2.0 + RESULT_POLL_S)
    key, asked, tag = out.queries[-1]
    assert key == "fleet/r1/nav/result" and asked == {"goal_id": HEX}  # the first one, preempted: how did it end?
    nav.on_query_reply(tag, True, encode(NavResult(found=False)), now=2.0)
    assert out.replies[5][0] == cdr.get_result_response(NavLayout.JAZZY, 0)  # forgotten by the service: UNKNOWN


def test_a_flood_of_goals_is_each_answered() -> None:
    nav, out = make()
    for call in range(1, MAX_ASKING + 11):
        nav.on_request(SEND_GOAL, call, send_goal_payload(uuid=call.to_bytes(16, "big")), None, now=1.0)
    assert len(out.queries) == MAX_ASKING  # the service is asked this many at once
    beyond = [call for call, (data, _) in out.replies.items() if data[4] == 0]
    assert beyond == list(range(MAX_ASKING + 1, MAX_ASKING + 11)) and "already wait" in out.errors[-1].reason
    for _, asked, tag in list(out.queries):
        nav.on_query_reply(tag, True, encode(NavGoalReply(accepted=True, goal_id=asked["goal_id"])), now=1.1)
    assert len(out.replies) == MAX_ASKING + 10 and nav.queries == {}
    nav.tick(1.1 + RESULT_POLL_S)  # every goal but the last is asked how it ended, once
    polls = out.queries[MAX_ASKING:]
    assert len(polls) == MAX_GOALS - 1 and {key for key, _, _ in polls} == {"fleet/r1/nav/result"}  # those remembered


def test_results_beyond_those_held_and_without_a_service_are_answered() -> None:
    nav, out = make()
    accept(nav, out)
    nav.on_feedback(feedback("executing"), now=1.5)
    for call in range(10, 10 + MAX_WAITING + 1):
        nav.on_request(GET_RESULT, call, H + UUID, None, now=2.0)
    assert list(out.replies) == [1, 10 + MAX_WAITING]  # the one beyond: its state now (EXECUTING), not an error
    assert out.replies[10 + MAX_WAITING][0] == cdr.get_result_response(NavLayout.JAZZY, 2) and "already wait" in out.errors[-1].reason
    other = bytes(16 * [0xEE])
    nav.on_request(GET_RESULT, 99, H + other, None, now=3.0)
    nav.on_query_done(out.queries[-1][2], now=5.0)  # no navigation service answered
    assert out.replies[99][0] == cdr.get_result_response(NavLayout.JAZZY, 0) and out.refused == {}


def test_a_held_result_ends_when_the_navigation_goes_away() -> None:
    nav, out = make()
    accept(nav, out)
    nav.on_feedback(feedback("executing"), now=1.5)
    nav.on_request(GET_RESULT, 2, H + UUID, None, now=1.6)
    nav.on_alive(False, now=2.0)  # its liveliness token is gone: killed, or its host lost
    response = out.replies[2][0]
    assert response[4] == 6 and b"went away" in response and status_list(out.topic(STATUS)[-1]) == [(UUID, 6)]
    nav.on_alive(True, now=3.0)  # back: its map frame asked again
    assert out.queries[-1][0] == "fleet/r1/nav/map_pose"


def test_a_held_result_ends_when_nobody_answers_its_polls() -> None:
    nav, out = make()
    accept(nav, out)
    nav.on_feedback(feedback("executing"), now=1.5)
    nav.on_request(GET_RESULT, 2, H + UUID, None, now=1.6)
    for second in range(1, 4):
        nav.tick(1.6 + second * RESULT_POLL_S)
        nav.on_query_done(out.queries[-1][2], now=1.6 + second * RESULT_POLL_S + 0.5)  # nobody serves nav/result
    assert out.replies[2][0][4] == 6 and b"no navigation service answered" in out.replies[2][0]
