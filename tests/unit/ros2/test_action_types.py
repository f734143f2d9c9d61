"""The navigate_to_pose action's types: the adapter's definitions are the genuine ones (vendored in
tests/ros2_interfaces/, their sources in its README), and its type hashes come from rosidl's construction of an action,
which reproduces ROS 2 Jazzy's published hashes of action_tutorials_interfaces' Fibonacci."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from blackmetal.ros2.action_types import (
    CANCEL_GOAL,
    CANCEL_GOAL_DEFINITION,
    DEFINITIONS,
    FEEDBACK_MESSAGE,
    GET_RESULT,
    GOAL_STATUS_ARRAY,
    SEND_GOAL,
    NavLayout,
    action_hashes,
    action_type_definitions,
    layout_of,
    nav_services,
    nav_topics,
    register,
    service_type_definitions,
)
from blackmetal.ros2.naming import TRANSIENT_LOCAL, Direction, Distro, Qos
from blackmetal.ros2.ros_types import type_store

INTERFACES = Path(__file__).parents[2] / "ros2_interfaces"

#: ROS 2 Jazzy's hashes as rosidl generates them (written down, not computed here).
FIBONACCI = {
    "Fibonacci_SendGoal": "RIHS01_a0603060ed69fe2dfbd1a6f3b982a1749957ef346e4a4d2b311a05e305ec37bb",
    "Fibonacci_GetResult": "RIHS01_8b47e383f1e31f6d8df6417ab54957e7d5ea24dad315646ad711ac3fdea81d58",
    "Fibonacci_FeedbackMessage": "RIHS01_50fc26b9cac313652ecbeab3adf9b5414d59fd4d4d5f9058ddcc7525169927f1",
}
CANCEL_GOAL_HASH = "RIHS01_573d8b0a534451d7bc2ac8c5ffde8ac14b8593b7001175d0cd6516dcbeb8689a"
GOAL_STATUS_ARRAY_HASH = "RIHS01_6c1684b00f177d37438febe6e709fc4e2b0d4248dca4854946f9ed8b30cda83e"
#: NavigateToPose's, computed by that construction from the vendored definitions; written down so a change shows.
SEND_GOAL_HASH = "RIHS01_a4fcb3bee1bf32e21a0e541a943b221aa0826996e2c98f079b47022b256f48b5"
GET_RESULT_HASH = "RIHS01_c407920357d566771e8882b4ef4d1f1a84ee922d609920ccd57faa6d6e391dc5"
FEEDBACK_HASH = {
    NavLayout.JAZZY: "RIHS01_9d1f6fa2eb975ce733b419ac2e97b134d8ff92b6478b6559feed9a50bdfd82b3",
    NavLayout.ROLLING: "RIHS01_2c1b4ec1a0e3a53c9aa326aabe717670eeef0ff3d4c3351ff940613b2011728a",
}


def fields_of(text: str) -> list[str]:
    """A .msg section's fields, as rosidl hashes them: no comments, no constants, short names made full."""
    out = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line or "=" in line:
            continue
        kind, name = line.split()
        if "/" in kind and "/msg/" not in kind:
            kind = kind.replace("/", "/msg/")
        out.append(f"{kind} {name}")
    return out


def test_action_hashes_by_rosidls_construction_reproduce_jazzys_own() -> None:
    store = type_store()
    definitions = action_type_definitions(
        "action_tutorials_interfaces/action/Fibonacci", "int32 order", "int32[] sequence", "int32[] partial_sequence"
    )
    register(store, {**definitions, **service_type_definitions(CANCEL_GOAL, *CANCEL_GOAL_DEFINITION)})
    for name, expected in FIBONACCI.items():
        assert store.hash_rihs01(f"action_tutorials_interfaces/action/{name}") == expected
    assert store.hash_rihs01(CANCEL_GOAL) == CANCEL_GOAL_HASH
    assert store.hash_rihs01(GOAL_STATUS_ARRAY) == GOAL_STATUS_ARRAY_HASH


@pytest.mark.parametrize(
    ("branch", "layout"),
    [
        ("humble", NavLayout.HUMBLE),
        ("jazzy", NavLayout.JAZZY),
        ("kilted", NavLayout.JAZZY),
        ("lyrical", NavLayout.ROLLING),
        ("rolling", NavLayout.ROLLING),
    ],
)
def test_definitions_are_navigation2s_on_each_branch(branch: str, layout: NavLayout) -> None:
    goal, result, feedback = (INTERFACES / branch / "nav2_msgs/action/NavigateToPose.action").read_text().split("---")
    ours = DEFINITIONS[layout]
    assert [fields_of(s) for s in (goal, result, feedback)] == [fields_of(s) for s in ours]
    assert layout_of(Distro(branch)) is layout


def test_action_msgs_and_uuid_are_rcl_interfaces() -> None:
    request, response = (INTERFACES / "jazzy/action_msgs/srv/CancelGoal.srv").read_text().split("---")
    assert fields_of(request) == ["GoalInfo goal_info"] and CANCEL_GOAL_DEFINITION[0] == "action_msgs/msg/GoalInfo goal_info"
    assert fields_of(response)[1] == "GoalInfo[] goals_canceling"
    assert fields_of(CANCEL_GOAL_DEFINITION[1])[0] == fields_of(response)[0] == "int8 return_code"
    assert fields_of((INTERFACES / "jazzy/unique_identifier_msgs/msg/UUID.msg").read_text()) == ["uint8[16] uuid"]
    store = type_store()  # rosbags' own action_msgs and UUID: the same fields
    assert [name for name, _ in store.fielddefs["unique_identifier_msgs/msg/UUID"][1]] == ["uuid"]
    assert [name for name, _ in store.fielddefs["action_msgs/msg/GoalInfo"][1]] == ["goal_id", "stamp"]
    status = fields_of((INTERFACES / "jazzy/action_msgs/msg/GoalStatus.msg").read_text())
    assert status == ["GoalInfo goal_info", "int8 status"]


def test_hashes_per_layout() -> None:
    for layout in (NavLayout.JAZZY, NavLayout.ROLLING):
        hashes = action_hashes(layout)
        assert hashes[SEND_GOAL] == SEND_GOAL_HASH and hashes[GET_RESULT] == GET_RESULT_HASH
        assert hashes[FEEDBACK_MESSAGE] == FEEDBACK_HASH[layout]
        assert hashes[CANCEL_GOAL] == CANCEL_GOAL_HASH and hashes[GOAL_STATUS_ARRAY] == GOAL_STATUS_ARRAY_HASH
        assert all(re.fullmatch(r"RIHS01_[0-9a-f]{64}", h) for h in hashes.values())


def test_the_actions_entities() -> None:
    topics = {t.name: t for t in nav_topics()}
    assert (
        topics["navigate_to_pose/_action/feedback"].qos == Qos()
        and topics["navigate_to_pose/_action/feedback"].ros_type == FEEDBACK_MESSAGE
    )
    assert topics["navigate_to_pose/_action/status"].qos == TRANSIENT_LOCAL  # rcl_action's status: keep-last 1, transient local
    assert TRANSIENT_LOCAL.keyexpr() == ":1:,1:,:,:,,"
    assert topics["goal_pose"].direction is topics["initialpose"].direction is Direction.SUBSCRIBE
    assert [(s.name, s.ros_type) for s in nav_services()] == [
        ("navigate_to_pose/_action/send_goal", SEND_GOAL),
        ("navigate_to_pose/_action/cancel_goal", CANCEL_GOAL),
        ("navigate_to_pose/_action/get_result", GET_RESULT),
    ]
    assert nav_services()[0].full_name("/r1", "blackmetal") == "/r1/navigate_to_pose/_action/send_goal"
