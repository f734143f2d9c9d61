"""The action's CDR, written and read by hand: held to bytes worked out by hand from the IDL layout, and to rosbags'
serializer for the genuine definitions (Humble's, Jazzy's and Rolling's NavigateToPose)."""

from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np
import pytest

from blackmetal.ros2 import action_cdr as cdr
from blackmetal.ros2.action_types import (
    CANCEL_GOAL,
    CANCEL_GOAL_DEFINITION,
    DEFINITIONS,
    FEEDBACK_MESSAGE,
    GET_RESULT,
    GOAL_STATUS_ARRAY,
    PACKAGE,
    POSE_WITH_COVARIANCE_STAMPED,
    SEND_GOAL,
    NavLayout,
    action_type_definitions,
    register,
    service_type_definitions,
)
from blackmetal.ros2.ros_types import type_store
from blackmetal.schemas import PayloadError

UUID = bytes(range(1, 17))
H = b"\x00\x01\x00\x00"


@pytest.fixture(scope="module", params=list(NavLayout))
def store(request: pytest.FixtureRequest) -> tuple[NavLayout, Any]:
    s = type_store()
    register(
        s,
        {**action_type_definitions(PACKAGE, *DEFINITIONS[request.param]), **service_type_definitions(CANCEL_GOAL, *CANCEL_GOAL_DEFINITION)},
    )
    return request.param, s


def msg(s: Any, name: str, **fields: Any) -> Any:
    return s.types[name](**fields)


def pose_stamped(s: Any, frame: str, x: float, y: float, yaw: float) -> Any:
    return msg(
        s,
        "geometry_msgs/msg/PoseStamped",
        header=msg(s, "std_msgs/msg/Header", stamp=msg(s, "builtin_interfaces/msg/Time", sec=5, nanosec=6), frame_id=frame),
        pose=msg(
            s,
            "geometry_msgs/msg/Pose",
            position=msg(s, "geometry_msgs/msg/Point", x=x, y=y, z=0.0),
            orientation=msg(s, "geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
        ),
    )


def uuid_msg(s: Any, uuid: bytes) -> Any:
    return msg(s, "unique_identifier_msgs/msg/UUID", uuid=np.frombuffer(uuid, dtype=np.uint8))


def test_responses_against_bytes_worked_out_by_hand() -> None:
    # bool accepted, 3 bytes of padding to the int32 sec, uint32 nanosec
    assert cdr.send_goal_response(True, 1, 2) == H + b"\x01\x00\x00\x00" + struct.pack("<iI", 1, 2)
    # int8 status, then Humble's std_msgs/Empty: its one placeholder byte
    assert cdr.get_result_response(NavLayout.HUMBLE, 4) == H + b"\x04\x00"
    # int8 status, pad 1 to the uint16 error_code (9000 = 0x2328), uint32 length 2 with the NUL, "x\0"
    assert cdr.get_result_response(NavLayout.JAZZY, 6, 9000, "x") == H + b"\x06\x00\x28\x23" + b"\x02\x00\x00\x00x\x00"
    # int8 return_code, pad 3, uint32 count, then each GoalInfo: 16 uuid bytes, int32 sec, uint32 nanosec
    assert cdr.cancel_goal_response(0, [(UUID, 1, 2)]) == H + b"\x00\x00\x00\x00" + b"\x01\x00\x00\x00" + UUID + struct.pack("<iI", 1, 2)
    assert cdr.cancel_goal_response(2, []) == H + b"\x02\x00\x00\x00" + b"\x00\x00\x00\x00"
    # uint32 count, GoalInfo, int8 status; the next uuid (bytes) follows at once, its int32 sec 4-aligned after it
    two = cdr.status_array([((UUID, 1, 2), 2), ((UUID, 3, 4), 5)])
    second = UUID + b"\x00\x00\x00" + struct.pack("<iIb", 3, 4, 5)
    assert two == H + b"\x02\x00\x00\x00" + UUID + struct.pack("<iIb", 1, 2, 2) + second


def test_send_goal_request_read_from_bytes_worked_out_by_hand() -> None:
    # uuid, Time, frame_id "map" (length 4), the 7 doubles from offset 32 (8-aligned), behavior_tree "" (length 1)
    body = UUID + struct.pack("<iII", 7, 8, 4) + b"map\x00" + struct.pack("<7d", 1.5, -2.0, 0.0, 0.0, 0.0, math.sin(0.5), math.cos(0.5))
    body += struct.pack("<I", 1) + b"\x00"
    uuid, pose, tree = cdr.send_goal_request(H + body)
    assert uuid == UUID and tree == "" and (pose.sec, pose.nanosec, pose.frame, pose.x, pose.y) == (7, 8, "map", 1.5, -2.0)
    assert pose.yaw == pytest.approx(1.0)
    assert cdr.send_goal_request(H + body + b"\x00\x00\x00")[0] == UUID  # a writer's padding to 4 is taken


def test_ours_equal_rosbags_for_the_genuine_definitions(store: tuple[NavLayout, Any]) -> None:
    layout, s = store
    request = msg(
        s,
        f"{SEND_GOAL}_Request",
        goal_id=uuid_msg(s, UUID),
        goal=msg(s, f"{PACKAGE}_Goal", pose=pose_stamped(s, "odom", 3.0, 4.0, -2.0), behavior_tree="bt.xml"),
    )
    uuid, pose, tree = cdr.send_goal_request(bytes(s.serialize_cdr(request, f"{SEND_GOAL}_Request")))
    assert (uuid, pose.frame, pose.x, pose.y, tree) == (UUID, "odom", 3.0, 4.0, "bt.xml") and pose.yaw == pytest.approx(-2.0)
    big = bytes(s.serialize_cdr(request, f"{SEND_GOAL}_Request", little_endian=False))
    assert cdr.send_goal_request(big)[1] == pose  # a big-endian writer too

    time = msg(s, "builtin_interfaces/msg/Time", sec=1, nanosec=2)
    response = msg(s, f"{SEND_GOAL}_Response", accepted=True, stamp=time)
    assert cdr.send_goal_response(True, 1, 2) == bytes(s.serialize_cdr(response, f"{SEND_GOAL}_Response"))

    if layout is NavLayout.HUMBLE:
        result = msg(s, f"{PACKAGE}_Result", result=msg(s, "std_msgs/msg/Empty", structure_needs_at_least_one_member=0))
    else:
        result = msg(s, f"{PACKAGE}_Result", error_code=9000, error_msg="e-stop engaged")
    ours = cdr.get_result_response(layout, 6, 9000, "e-stop engaged")
    assert ours == bytes(s.serialize_cdr(msg(s, f"{GET_RESULT}_Response", status=6, result=result), f"{GET_RESULT}_Response"))
    get = bytes(s.serialize_cdr(msg(s, f"{GET_RESULT}_Request", goal_id=uuid_msg(s, UUID)), f"{GET_RESULT}_Request"))
    assert cdr.get_result_request(get) == UUID

    info = msg(s, "action_msgs/msg/GoalInfo", goal_id=uuid_msg(s, UUID), stamp=time)
    cancel = bytes(s.serialize_cdr(msg(s, f"{CANCEL_GOAL}_Request", goal_info=info), f"{CANCEL_GOAL}_Request"))
    assert cdr.cancel_goal_request(cancel) == (UUID, 1, 2)
    answer = msg(s, f"{CANCEL_GOAL}_Response", return_code=0, goals_canceling=[info])
    assert cdr.cancel_goal_response(0, [(UUID, 1, 2)]) == bytes(s.serialize_cdr(answer, f"{CANCEL_GOAL}_Response"))
    statuses = msg(s, GOAL_STATUS_ARRAY, status_list=[msg(s, "action_msgs/msg/GoalStatus", goal_info=info, status=4)] * 2)
    assert cdr.status_array([((UUID, 1, 2), 4)] * 2) == bytes(s.serialize_cdr(statuses, GOAL_STATUS_ARRAY))

    values = cdr.Feedback(5, 6, "map", 1.0, 2.0, 0.5, 3.25, 7.5, 0, 2.5)
    fields: dict[str, Any] = {
        "current_pose": pose_stamped(s, "map", 1.0, 2.0, 0.5),
        "navigation_time": msg(s, "builtin_interfaces/msg/Duration", sec=3, nanosec=250_000_000),
        "estimated_time_remaining": msg(s, "builtin_interfaces/msg/Duration", sec=7, nanosec=500_000_000),
        "number_of_recoveries": 0,
        "distance_remaining": 2.5,
    }
    if layout is NavLayout.ROLLING:
        fields |= {"position_tracking_error": 0.0, "heading_tracking_error": 0.0}
    message = msg(s, FEEDBACK_MESSAGE, goal_id=uuid_msg(s, UUID), feedback=msg(s, f"{PACKAGE}_Feedback", **fields))
    assert cdr.feedback_message(layout, UUID, values) == bytes(s.serialize_cdr(message, FEEDBACK_MESSAGE))


def test_rviz_poses() -> None:
    s = type_store()
    stamped = pose_stamped(s, "map", 1.0, -1.0, 3.0)
    pose = cdr.pose_stamped(bytes(s.serialize_cdr(stamped, "geometry_msgs/msg/PoseStamped")))
    assert (pose.frame, pose.x, pose.y) == ("map", 1.0, -1.0) and pose.yaw == pytest.approx(3.0)
    with_covariance = msg(
        s,
        POSE_WITH_COVARIANCE_STAMPED,
        header=stamped.header,
        pose=msg(s, "geometry_msgs/msg/PoseWithCovariance", pose=stamped.pose, covariance=np.arange(36, dtype=np.float64)),
    )
    estimate = cdr.pose_with_covariance_stamped(bytes(s.serialize_cdr(with_covariance, POSE_WITH_COVARIANCE_STAMPED)))
    assert estimate == pose
    # an all-zero orientation asks for no heading
    zero = H + struct.pack("<iII", 0, 0, 1) + b"\x00" + b"\x00" * 3 + struct.pack("<7d", 1, 2, 0, 0, 0, 0, 0)
    assert cdr.pose_stamped(zero).yaw is None and cdr.pose_stamped(zero).frame == ""


def test_bad_payloads_each_get_a_sentence() -> None:
    good = H + UUID + struct.pack("<iII", 0, 0, 4) + b"map\x00" + struct.pack("<7d", 1, 2, 0, 0, 0, 0, 1) + struct.pack("<I", 1) + b"\x00"
    bad = {
        "empty": b"",
        "a JSON goal": b'{"x": 1, "y": 2}',
        "truncated": good[:40],
        "too long": good + b"\x00" * 8,
        "NaN": good[:36] + struct.pack("<d", math.nan) + good[44:],
        "infinite": good[:44] + struct.pack("<d", math.inf) + good[52:],
        "frame_id without its NUL": good[:32] + b"mapX" + good[36:],
        "frame_id not UTF-8": good[:32] + b"\xff\xfe\x00\x00" + good[36:],
    }
    for why, payload in bad.items():
        with pytest.raises(PayloadError) as caught:
            cdr.send_goal_request(payload)
        assert "NavigateToPose_SendGoal_Request" in str(caught.value), why
    with pytest.raises(PayloadError, match="finite"):
        cdr.send_goal_request(bad["NaN"])
    with pytest.raises(PayloadError, match="left over"):
        cdr.cancel_goal_request(H + bytes(16) + bytes(8) + bytes(8))


def test_durations() -> None:
    assert cdr.duration(3.25) == (3, 250_000_000)
    assert cdr.duration(-1.0) == (0, 0) and cdr.duration(math.inf) == (0, 0)
    assert cdr.duration(0.9999999999) == (0, 999_999_999)
