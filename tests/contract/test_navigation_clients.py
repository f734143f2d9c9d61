"""The independent navigation clients held to the genuine definitions, before they are trusted to judge the product.

tests/free_fleet_client.py lays its messages out as free_fleet's ``ros2_types.py`` does (pycdr2, some types
flattened: the goal id's UUID as 16 bytes, the goal's fields inline, the result left out);
tests/rmw_action_client.py (with tests/ros2_idl.py) parses the vendored ``.msg`` / ``.srv`` / ``.action`` files
(tests/ros2_interfaces/README.md says where from) into rosidl's structures, writes CDR from them and
hashes them as REP-2011 says. Here each is checked against something it was not written from:

* the bytes of every free_fleet type = the bytes of the genuine (nested) type written by the
  definition-driven writer = the bytes rosbags' serializer writes for types it registers from the
  same ``.msg`` text (the ``.action``'s sections fed to rosbags' own parser);
* the RIHS01 hashes = rosbags' for every message type, and rmw_zenoh's published hash of
  ``example_interfaces/srv/AddTwoInts`` (its docs/design.md) for a service (the ``_Event`` message and
  ``service_msgs/ServiceEventInfo``'s ``char[16]``, which rosidl reads as ``uint8[16]``);
* the tf2 emulation (tests/tf2_buffer.py) and the key / token / attachment formats, on their own.

No processes, no network: pure.
"""

from __future__ import annotations

import math
import re
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import xxhash
from free_fleet_client import (
    UUID,
    BatteryState,
    CancelGoalRequest,
    CancelGoalResponse,
    Duration,
    FeedbackMessage,
    GetResultRequest,
    GetResultResponse,
    GoalInfo,
    GoalStatus,
    Header,
    Point,
    Pose,
    PoseStamped,
    Quaternion,
    SendGoalRequest,
    SendGoalResponse,
    TfBuffer,
    TfLookupError,
    TFMessage,
    Time,
    Transform,
    TransformStamped,
    Vector3,
    cancel_all_request,
    namespacify,
)
from rmw_action_client import (
    DISTROS,
    EMPTY_MEMBER,
    INTERFACES,
    ActionClient,
    FieldType,
    Interfaces,
    attachment,
    dds_type,
    read_attachment,
)
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype

NAV = "nav2_msgs/action/NavigateToPose"
#: The Jazzy hashes of the action's five entities (the same on Kilted: only constants changed there). Computed here;
#: the ROS 2 adapter's helper computed the same values with rosbags (its NAV_KEYS.md), independently.
JAZZY_HASHES = {
    f"{NAV}_SendGoal": "RIHS01_a4fcb3bee1bf32e21a0e541a943b221aa0826996e2c98f079b47022b256f48b5",
    f"{NAV}_GetResult": "RIHS01_c407920357d566771e8882b4ef4d1f1a84ee922d609920ccd57faa6d6e391dc5",
    f"{NAV}_FeedbackMessage": "RIHS01_9d1f6fa2eb975ce733b419ac2e97b134d8ff92b6478b6559feed9a50bdfd82b3",
    "action_msgs/srv/CancelGoal": "RIHS01_573d8b0a534451d7bc2ac8c5ffde8ac14b8593b7001175d0cd6516dcbeb8689a",
    "action_msgs/msg/GoalStatusArray": "RIHS01_6c1684b00f177d37438febe6e709fc4e2b0d4248dca4854946f9ed8b30cda83e",
}
#: example_interfaces/srv/AddTwoInts.srv (ros2/example_interfaces, branch jazzy) and its key in rmw_zenoh's
#: docs/design.md ("add_two_ints service with DOMAIN_ID=2"): the published hash of a service, event message included.
ADD_TWO_INTS = "int64 a\nint64 b\n---\nint64 sum\n"
ADD_TWO_INTS_KEY = (
    "2/add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
)


# ------------------------------------------------------------------ rosbags, from the vendored text
def rosbags_store(distro: str) -> Any:
    """A rosbags type store holding only what tests/ros2_interfaces/<distro> defines, parsed by rosbags itself; an
    action's sections and the types rosidl derives from it (definition.py's Action) registered as messages."""
    store = get_typestore(Stores.EMPTY)
    root = INTERFACES / distro
    for path in sorted(root.glob("*/msg/*.msg")):
        store.register(get_types_from_msg(path.read_text(), f"{path.parts[-3]}/msg/{path.stem}"))
    for path in sorted(root.glob("*/srv/*.srv")):
        request, response = re.split(r"^---\s*$", path.read_text(), flags=re.M)
        package = path.parts[-3]
        store.register(get_types_from_msg(request, f"{package}/msg/{path.stem}_Request"))
        store.register(get_types_from_msg(response, f"{package}/msg/{path.stem}_Response"))
    for path in sorted(root.glob("*/action/*.action")):
        goal, result, feedback = re.split(r"^---\s*$", path.read_text(), flags=re.M)
        package, name = path.parts[-3], path.stem
        own = f"{package}/{name}"
        derived = {
            "Goal": goal,
            "Result": result,
            "Feedback": feedback,
            "SendGoal_Request": f"unique_identifier_msgs/UUID goal_id\n{own}_Goal goal\n",
            "SendGoal_Response": "bool accepted\nbuiltin_interfaces/Time stamp\n",
            "GetResult_Request": "unique_identifier_msgs/UUID goal_id\n",
            "GetResult_Response": f"int8 status\n{own}_Result result\n",
            "FeedbackMessage": f"unique_identifier_msgs/UUID goal_id\n{own}_Feedback feedback\n",
        }
        for suffix, text in derived.items():
            store.register(get_types_from_msg(text, f"{package}/msg/{name}_{suffix}"))
    return store


def as_msg_name(typename: str) -> str:
    """rosbags holds every derived type as ``pkg/msg/Name``."""
    package, _, name = typename.split("/")
    return f"{package}/msg/{name}"


def rosbags_message(store: Any, typename: str, value: dict[str, Any]) -> Any:
    """A rosbags message from nested dicts (missing fields zero), numpy arrays where rosbags wants them."""
    _, fields = store.fielddefs[typename]
    args: dict[str, Any] = {}
    for name, (kind, rest) in fields:
        item = value.get(name)
        if kind == Nodetype.NAME:
            args[name] = rosbags_message(store, rest, item or {})
        elif kind == Nodetype.BASE:
            args[name] = item if item is not None else ("" if rest[0] == "string" else 0)
        else:
            (inner_kind, inner), size = rest
            items = list(item or ([] if kind == Nodetype.SEQUENCE else [None] * size))
            if inner_kind == Nodetype.NAME:
                args[name] = [rosbags_message(store, inner, one or {}) for one in items]
            elif inner[0] == "string":
                args[name] = [str(one or "") for one in items]
            else:
                dtype = {"float32": np.float32, "float64": np.float64, "uint8": np.uint8, "char": np.uint8, "int8": np.int8}[inner[0]]
                args[name] = np.asarray([one or 0 for one in items], dtype=dtype)
    return store.types[typename](**args)


# ------------------------------------------------------------------ sample values, the genuine (nested) shapes
STAMP = {"sec": 1_764_000_000, "nanosec": 123_456_789}
GOAL_ID = list(range(1, 17))
POSE = {
    "header": {"stamp": STAMP, "frame_id": "map"},
    "pose": {"position": {"x": 1.25, "y": -3.5, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(0.4), "w": math.cos(0.4)}},
}
ODD_POSE = {**POSE, "header": {"stamp": STAMP, "frame_id": "r12/odom"}}  # 8 bytes of frame id: the alignment after it moves
FEEDBACK = {
    "current_pose": ODD_POSE,
    "navigation_time": {"sec": 3, "nanosec": 500_000_000},
    "estimated_time_remaining": {"sec": 7, "nanosec": 250_000_000},
    "number_of_recoveries": 0,
    "distance_remaining": 2.5,
}
TRANSFORMS = {
    "transforms": [
        {
            "header": {"stamp": STAMP, "frame_id": "map"},
            "child_frame_id": "odom",
            "transform": {"translation": {"x": 2.0, "y": 1.0, "z": 0.0}, "rotation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
        },
        {
            "header": {"stamp": STAMP, "frame_id": "odom"},
            "child_frame_id": "base_footprint",
            "transform": {"translation": {"x": 0.5, "y": 0.0, "z": 0.0}, "rotation": {"x": 0.0, "y": 0.0, "z": 0.1, "w": math.sqrt(0.99)}},
        },
    ]
}
BATTERY = {
    "header": {"stamp": STAMP, "frame_id": "base_link"},
    "voltage": 12.5,
    "temperature": float("nan"),
    "current": -1.5,
    "charge": float("nan"),
    "capacity": float("nan"),
    "design_capacity": 24.0,
    "percentage": 0.75,
    "power_supply_status": 2,
    "power_supply_health": 1,
    "power_supply_technology": 2,
    "present": True,
    "cell_voltage": [4.1, 4.2, 4.15],
    "cell_temperature": [],
    "location": "slot",
    "serial_number": "BM-0001",
}
CANCEL_RESPONSE = {"return_code": 0, "goals_canceling": [{"goal_id": {"uuid": GOAL_ID}, "stamp": STAMP}]}


def t(value: dict[str, int]) -> Time:
    return Time(sec=value["sec"], nanosec=value["nanosec"])


def pose_stamped(value: dict[str, Any]) -> PoseStamped:
    p, q = value["pose"]["position"], value["pose"]["orientation"]
    return PoseStamped(
        header=Header(stamp=t(value["header"]["stamp"]), frame_id=value["header"]["frame_id"]),
        pose=Pose(position=Point(**p), orientation=Quaternion(**q)),
    )


def transform_stamped(value: dict[str, Any]) -> TransformStamped:
    v, q = value["transform"]["translation"], value["transform"]["rotation"]
    return TransformStamped(
        header=Header(stamp=t(value["header"]["stamp"]), frame_id=value["header"]["frame_id"]),
        child_frame_id=value["child_frame_id"],
        transform=Transform(translation=Vector3(**v), rotation=Quaternion(**q)),
    )


#: (free_fleet's type built from the sample, the genuine type, the sample in its genuine shape)
CASES: dict[str, tuple[Any, str, dict[str, Any]]] = {
    "send_goal request": (
        SendGoalRequest(goal_id=GOAL_ID, pose=pose_stamped(POSE), behavior_tree=""),
        f"{NAV}_SendGoal_Request",
        {"goal_id": {"uuid": GOAL_ID}, "goal": {"pose": POSE, "behavior_tree": ""}},
    ),
    "send_goal request, a behaviour tree": (
        SendGoalRequest(goal_id=GOAL_ID, pose=pose_stamped(ODD_POSE), behavior_tree="navigate.xml"),
        f"{NAV}_SendGoal_Request",
        {"goal_id": {"uuid": GOAL_ID}, "goal": {"pose": ODD_POSE, "behavior_tree": "navigate.xml"}},
    ),
    "send_goal response": (SendGoalResponse(accepted=True, stamp=t(STAMP)), f"{NAV}_SendGoal_Response", {"accepted": True, "stamp": STAMP}),
    "get_result request": (GetResultRequest(goal_id=GOAL_ID), f"{NAV}_GetResult_Request", {"goal_id": {"uuid": GOAL_ID}}),
    "feedback message": (
        FeedbackMessage(
            goal_id=GOAL_ID,
            current_pose=pose_stamped(ODD_POSE),
            navigation_time=Duration(sec=3, nanosec=500_000_000),
            estimated_time_remaining=Duration(sec=7, nanosec=250_000_000),
            number_of_recoveries=0,
            distance_remaining=2.5,
        ),
        f"{NAV}_FeedbackMessage",
        {"goal_id": {"uuid": GOAL_ID}, "feedback": FEEDBACK},
    ),
    "tf": (TFMessage(transforms=[transform_stamped(x) for x in TRANSFORMS["transforms"]]), "tf2_msgs/msg/TFMessage", TRANSFORMS),
    "cancel-all request": (
        cancel_all_request(),
        "action_msgs/srv/CancelGoal_Request",
        {"goal_info": {"goal_id": {"uuid": [0] * 16}, "stamp": {"sec": 0, "nanosec": 0}}},
    ),
    "cancel one request": (
        CancelGoalRequest(goal_info=GoalInfo(goal_id=UUID(uuid=GOAL_ID), stamp=t(STAMP))),
        "action_msgs/srv/CancelGoal_Request",
        {"goal_info": {"goal_id": {"uuid": GOAL_ID}, "stamp": STAMP}},
    ),
    "cancel response": (
        CancelGoalResponse(return_code=0, goals_canceling=[GoalInfo(goal_id=UUID(uuid=GOAL_ID), stamp=t(STAMP))]),
        "action_msgs/srv/CancelGoal_Response",
        CANCEL_RESPONSE,
    ),
    "battery state": (
        BatteryState(
            header=Header(stamp=t(STAMP), frame_id="base_link"),
            **{k: v for k, v in BATTERY.items() if k != "header"},
        ),
        "sensor_msgs/msg/BatteryState",
        BATTERY,
    ),
}


def same_bytes(a: bytes, b: bytes) -> bool:
    return bytes(a) == bytes(b)


# ------------------------------------------------------------------ free_fleet's layouts against the definitions
@pytest.mark.parametrize("distro", DISTROS)
@pytest.mark.parametrize("case", sorted(CASES))
def test_free_fleets_bytes_are_the_genuine_types_bytes(case: str, distro: str) -> None:
    ours, typename, genuine = CASES[case]
    interfaces = Interfaces(distro)
    store = rosbags_store(distro)
    by_definition = interfaces.serialize(typename, genuine)
    by_rosbags = bytes(store.serialize_cdr(rosbags_message(store, as_msg_name(typename), genuine), as_msg_name(typename)))
    assert same_bytes(ours.serialize(), by_definition), f"{case}: pycdr2 {ours.serialize().hex()} != definition {by_definition.hex()}"
    assert same_bytes(by_rosbags, by_definition), f"{case}: rosbags {by_rosbags.hex()} != definition {by_definition.hex()}"
    # and back: free_fleet reads the genuine bytes as the value it wrote, the definition-driven reader as the sample
    assert type(ours).deserialize(by_rosbags).serialize() == ours.serialize()  # NaN != NaN: compared as bytes
    back = interfaces.deserialize(typename, by_rosbags)
    assert interfaces.serialize(typename, back) == by_definition


@pytest.mark.parametrize(
    ("distro", "result", "result_bytes"),
    [
        ("humble", {}, b"\x00"),  # std_msgs/Empty: rosidl's structure_needs_at_least_one_member, one uint8
        ("jazzy", {"error_code": 9000, "error_msg": "e-stop engaged"}, None),
    ],
)
def test_free_fleet_reads_the_status_of_each_distros_get_result_response(
    distro: str, result: dict[str, Any], result_bytes: bytes | None
) -> None:
    interfaces, store = Interfaces(distro), rosbags_store(distro)
    typename = f"{NAV}_GetResult_Response"
    for status in GoalStatus:
        value = {"status": int(status), "result": result}
        genuine = interfaces.serialize(typename, value)
        by_rosbags = bytes(store.serialize_cdr(rosbags_message(store, as_msg_name(typename), value), as_msg_name(typename)))
        assert genuine == by_rosbags
        assert GetResultResponse.deserialize(genuine).status == status  # free_fleet's type: the status byte only
    if result_bytes is not None:
        assert interfaces.serialize(typename, {"status": 4}) == b"\x00\x01\x00\x00\x04" + result_bytes
        (empty,) = interfaces.fields("std_msgs/msg/Empty")
        assert empty.name == EMPTY_MEMBER


def test_the_cancel_all_request_is_a_zero_goal_id_and_a_zero_stamp() -> None:
    assert cancel_all_request().serialize() == b"\x00\x01\x00\x00" + b"\x00" * 24


def test_the_definitions_differ_between_humble_and_jazzy_only_where_the_readme_says() -> None:
    humble, jazzy = Interfaces("humble"), Interfaces("jazzy")
    names = {str(p.relative_to(INTERFACES / "jazzy").with_suffix("")) for p in (INTERFACES / "jazzy").rglob("*.*")}
    names.discard("service_msgs/msg/ServiceEventInfo")  # new in Iron
    differing = []
    for name in sorted(names):
        kind = name.split("/")[1]
        parts = (
            [f"{name}_{s}" for s in ("Goal", "Result", "Feedback")]
            if kind == "action"
            else [f"{name}_{s}" for s in ("Request", "Response")]
            if kind == "srv"
            else [name]
        )
        for part in parts:
            if humble.fields(part) != jazzy.fields(part):
                differing.append(part)
    assert differing == [f"{NAV}_Result"]
    assert [f.name for f in jazzy.fields(f"{NAV}_Result")] == ["error_code", "error_msg"]


# ------------------------------------------------------------------ REP-2011
@pytest.mark.parametrize("typename", sorted(p for p in ("action_msgs/msg/GoalStatusArray", "action_msgs/msg/GoalStatus", "action_msgs/msg/GoalInfo",
                                                        "geometry_msgs/msg/PoseStamped",
        "geometry_msgs/msg/PoseWithCovarianceStamped", "geometry_msgs/msg/TransformStamped", "tf2_msgs/msg/TFMessage",
                                                        "sensor_msgs/msg/BatteryState", "unique_identifier_msgs/msg/UUID", "std_msgs/msg/Empty",
                                                        "builtin_interfaces/msg/Duration")))  # fmt: skip
def test_message_hashes_are_rosbags_hashes(typename: str) -> None:
    assert Interfaces("jazzy").type_hash(typename) == get_typestore(Stores.ROS2_JAZZY).hash_rihs01(typename)


def test_a_service_hash_is_rmw_zenohs_published_one() -> None:
    """The service's type description holds its _Request, _Response and _Event (with ServiceEventInfo, whose
    ``char[16] client_gid`` rosidl reads as ``uint8[16]``: rosbags reads it as char, and its hash of
    ServiceEventInfo differs from rosidl's)."""
    interfaces = Interfaces("jazzy", extra={"example_interfaces/srv/AddTwoInts": ADD_TWO_INTS})
    typename = "example_interfaces/srv/AddTwoInts"
    assert f"2/add_two_ints/{dds_type(typename)}/{interfaces.type_hash(typename)}" == ADD_TWO_INTS_KEY
    gid = next(f for f in interfaces.fields("service_msgs/msg/ServiceEventInfo") if f.name == "client_gid")
    assert gid.type == FieldType("char", "array", 16)
    described = interfaces.type_description(typename)
    assert [d["type_name"] for d in described["referenced_type_descriptions"]] == [
        "builtin_interfaces/msg/Time",
        f"{typename}_Event",
        f"{typename}_Request",
        f"{typename}_Response",
        "service_msgs/msg/ServiceEventInfo",
    ]


def test_the_navigate_to_pose_hashes_per_distro() -> None:
    jazzy, humble = Interfaces("jazzy"), Interfaces("humble")
    for typename, expected in JAZZY_HASHES.items():
        assert jazzy.type_hash(typename) == expected, typename
        assert humble.type_hash(typename) == "TypeHashNotSupported"
    # what Humble's keys leave out: its result (std_msgs/Empty) differs, its goal and feedback do not
    assert jazzy.fields(f"{NAV}_GetResult_Response") == humble.fields(f"{NAV}_GetResult_Response")  # status, result
    assert jazzy.fields(f"{NAV}_Result") != humble.fields(f"{NAV}_Result")
    assert jazzy.fields(f"{NAV}_FeedbackMessage") == humble.fields(f"{NAV}_FeedbackMessage")


@pytest.mark.parametrize(
    ("distro", "feedback_hash"),
    [
        ("kilted", JAZZY_HASHES[f"{NAV}_FeedbackMessage"]),  # result constants only: nothing a hash sees
        ("rolling", "RIHS01_2c1b4ec1a0e3a53c9aa326aabe717670eeef0ff3d4c3351ff940613b2011728a"),  # + 2 feedback fields
    ],
)
def test_later_distros_hashes(distro: str, feedback_hash: str) -> None:
    """Kilted's and Rolling's NavigateToPose with Jazzy's other definitions; the values agree with the ones the ROS 2
    adapter's helper computed with rosbags (NAV_KEYS.md), independently of this implementation."""
    later = Interfaces(distro)  # its NavigateToPose, Jazzy's other definitions
    assert later.type_hash(f"{NAV}_FeedbackMessage") == feedback_hash
    for part in ("_SendGoal", "_GetResult"):
        assert later.type_hash(NAV + part) == JAZZY_HASHES[NAV + part]


# ------------------------------------------------------------------ tf2's lookup, as free_fleet uses it
def test_tf_lookup_resolves_map_to_base_footprint_at_the_latest_common_time() -> None:
    tf = TfBuffer()
    yaw = 0.3
    tf.set_transform("r1/map", "r1/odom", 100.0, (2.0, 1.0, 0.0), (0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)))
    for i in range(11):  # the robot drives along odom's x at 1 m/s, yawed 0.3
        tf.set_transform(
            "r1/odom", "r1/base_footprint", 99.5 + i * 0.1, (i * 0.1, 0.0, 0.0), (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
        )
    (x, y, _), q, when = tf.lookup("r1/map", "r1/base_footprint")
    assert when == 100.0  # map -> odom's stamp: the chain's latest common time
    assert (x, y) == pytest.approx((2.0, 1.0 + 0.5))  # odom's (0.5, 0) turned 90 degrees, then moved by (2, 1)
    assert math.atan2(2 * q[3] * q[2], 1 - 2 * q[2] ** 2) == pytest.approx(math.pi / 2 + yaw)


def test_tf_lookup_fails_as_tf2_does() -> None:
    tf = TfBuffer()
    with pytest.raises(TfLookupError):
        tf.lookup("map", "base_footprint")  # nothing yet
    tf.set_transform("odom", "base_footprint", 10.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    with pytest.raises(TfLookupError):
        tf.lookup("map", "base_footprint")  # odometry alone: no map -> odom
    tf.set_transform("map", "odom", 10.0, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    assert tf.lookup("map", "base_footprint")[0] == pytest.approx((1.0, 0.0, 0.0))
    for i in range(1, 120):  # odometry goes on for 12 s, map -> odom is never sent again: it falls out of the 10 s cache
        tf.set_transform("odom", "base_footprint", 10.0 + i * 0.1, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    with pytest.raises(TfLookupError, match="past"):
        tf.lookup("map", "base_footprint")
    assert not tf.set_transform("map", "odom", 30.0, (math.nan, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    assert not tf.set_transform("map", "odom", 30.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 2.0))


def test_free_fleet_names_keys_and_frames_by_the_robots_name() -> None:
    assert namespacify("navigate_to_pose/_action/send_goal", "r1") == "r1/navigate_to_pose/_action/send_goal"
    assert namespacify("map", "r1") == "r1/map" and namespacify("tf", "") == "tf"


# ------------------------------------------------------------------ rmw_zenoh's formats
class FakeLiveliness:
    def __init__(self) -> None:
        self.tokens: list[str] = []

    def declare_token(self, key: str) -> Any:
        self.tokens.append(key)
        return self


class FakeSession:
    """What ActionClient needs of a session to name its entities (no subscription is declared before the names)."""

    def __init__(self) -> None:
        self.lv = FakeLiveliness()

    def zid(self) -> str:
        return "1f2e3d"

    def liveliness(self) -> FakeLiveliness:
        return self.lv

    def declare_subscriber(self, *_: Any) -> None:
        raise _Named


class _Named(Exception):
    pass


@pytest.mark.parametrize("distro", DISTROS)
def test_the_action_clients_keys_and_tokens(distro: str) -> None:
    session = FakeSession()
    with pytest.raises(_Named):
        ActionClient(session, distro, "/r1/navigate_to_pose")  # type: ignore[arg-type]
    tokens = session.lv.tokens
    suffix = {"humble": lambda t: "TypeHashNotSupported", "jazzy": lambda t: JAZZY_HASHES[t]}[distro]
    assert tokens[0] == "@ros2_lv/0/1f2e3d/0/0/NN/%/%/navigate_client"
    expected = [
        ("SC", "send_goal", f"{NAV}_SendGoal", "::,10:,:,:,,"),
        ("SC", "cancel_goal", "action_msgs/srv/CancelGoal", "::,10:,:,:,,"),
        ("SC", "get_result", f"{NAV}_GetResult", "::,10:,:,:,,"),
        ("MS", "feedback", f"{NAV}_FeedbackMessage", "::,10:,:,:,,"),
        ("MS", "status", "action_msgs/msg/GoalStatusArray", ":1:,1:,:,:,,"),
    ]
    for number, (token, (kind, part, typename, qos)) in enumerate(zip(tokens[1:], expected, strict=True), start=1):
        assert token == (
            f"@ros2_lv/0/1f2e3d/0/{number}/{kind}/%/%/navigate_client/%r1%navigate_to_pose%_action%{part}/{dds_type(typename)}/{suffix(typename)}/{qos}"
        )
    assert dds_type(f"{NAV}_SendGoal") == "nav2_msgs::action::dds_::NavigateToPose_SendGoal_"


def test_the_attachment_is_rmw_zenohs_33_bytes() -> None:
    token = "@ros2_lv/0/1f2e3d/0/1/SC/%/%/n/%navigate_to_pose%_action%send_goal/t/h/::,10:,:,:,,"
    gid = xxhash.xxh3_128_intdigest(token.encode()).to_bytes(16, "little")
    raw = attachment(7, gid, timestamp_ns=1_764_000_000_123_456_789)
    assert len(raw) == 33 and raw[16] == 16 and struct.unpack_from("<q", raw)[0] == 7
    assert read_attachment(raw) == (7, 1_764_000_000_123_456_789, gid)
    with pytest.raises(ValueError, match="33"):
        read_attachment(raw[:-1])


@pytest.mark.parametrize("distro", DISTROS)
def test_the_definition_driven_reader_refuses_what_is_not_the_type(distro: str) -> None:
    interfaces = Interfaces(distro)
    good = interfaces.serialize(f"{NAV}_FeedbackMessage", {"goal_id": {"uuid": GOAL_ID}, "feedback": FEEDBACK})
    with pytest.raises((ValueError, struct.error)):
        interfaces.deserialize(f"{NAV}_FeedbackMessage", good[:-6])
    with pytest.raises(ValueError, match="left"):
        interfaces.deserialize(f"{NAV}_SendGoal_Response", good)
    with pytest.raises(ValueError, match="little-endian"):
        interfaces.deserialize(f"{NAV}_FeedbackMessage", b"\x00\x00\x00\x00" + good[4:])


def test_the_vendored_tree_is_what_the_readme_lists() -> None:
    readme = (INTERFACES / "README.md").read_text()
    for path in sorted(Path(INTERFACES).glob("*/*/*/*.*")):
        package, kind, name = path.parts[-3], path.parts[-2], path.stem
        assert package in readme and name in readme, f"{path}: not in tests/ros2_interfaces/README.md"
        assert kind in ("msg", "srv", "action")


# ------------------------------------------------------------------ the clients' own behaviour, against stand-in servers in this process
class FakeNav2:
    """A stand-in for a Nav2 action server behind zenoh-bridge-ros2dds, on one in-process session: what free_fleet's
    adapter asked (key, payload) and canned answers."""

    def __init__(self, session: Any, robot: str, status: int = 2) -> None:
        self.asked: list[tuple[str, bytes]] = []
        self.status = status
        self._queryables = [
            session.declare_queryable(f"{robot}/navigate_to_pose/_action/{part}", lambda q, part=part: self._answer(part, q))
            for part in ("send_goal", "get_result", "cancel_goal")
        ]

    def _answer(self, part: str, query: Any) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        self.asked.append((part, payload))
        if part == "send_goal":
            query.reply(query.key_expr, SendGoalResponse(accepted=True, stamp=Time(sec=1, nanosec=2)).serialize())
        elif part == "get_result":
            query.reply(query.key_expr, Interfaces("jazzy").serialize(f"{NAV}_GetResult_Response", {"status": self.status}))
        else:
            query.reply(query.key_expr, CancelGoalResponse(return_code=0, goals_canceling=[]).serialize())

    def close(self) -> None:
        for queryable in self._queryables:
            queryable.undeclare()


def test_the_free_fleet_client_makes_free_fleets_calls_in_its_order(session: Any) -> None:
    from free_fleet_client import FreeFleetRobot

    server = FakeNav2(session, "r1")
    robot = FreeFleetRobot(session, "r1", service_call_timeout_sec=1.0, clock=lambda: 1000.25)
    try:
        accepted, call = robot.navigate(1.0, 2.0, 0.5)
        assert accepted is True and call.key == "r1/navigate_to_pose/_action/send_goal"
        assert [part for part, _ in server.asked] == ["send_goal"]  # no goal held: no cancel first
        sent = SendGoalRequest.deserialize(server.asked[0][1])
        assert list(sent.goal_id) == robot.goal_id and all(0 <= b <= 254 for b in sent.goal_id)
        assert (sent.pose.header.frame_id, sent.pose.header.stamp.sec, sent.pose.header.stamp.nanosec) == ("map", 1000, 250_000_000)
        assert (sent.pose.pose.position.x, sent.pose.pose.position.y) == (1.0, 2.0) and sent.behavior_tree == ""
        assert sent.pose.pose.orientation.z == pytest.approx(math.sin(0.25))
        # feedback that says 5 s remain: free_fleet does not ask for the result before they are over
        feedback = FeedbackMessage(robot.goal_id, pose_stamped(POSE), Duration(1, 0), Duration(5, 0), 0, 1.0)
        session.put("r1/navigate_to_pose/_action/feedback", feedback.serialize())
        wait(lambda: robot.feedback_count == 1)
        assert robot.is_navigation_done() == (False, None) and len(server.asked) == 1
        robot.last_feedback = None
        assert robot.is_navigation_done() == (False, GoalStatus.EXECUTING)
        server.status = GoalStatus.SUCCEEDED
        assert robot.is_navigation_done() == (True, GoalStatus.SUCCEEDED)
        assert GetResultRequest.deserialize(server.asked[-1][1]).goal_id == bytes(robot.goal_id)
        # a new destination while a goal is held: cancel-all first, then the goal
        robot.navigate(3.0, 4.0, 0.0)
        assert [part for part, _ in server.asked[-2:]] == ["cancel_goal", "send_goal"]
        assert server.asked[-2][1] == cancel_all_request().serialize()
        # tf: frames namespaced by the robot's name, map -> base_footprint from the chain
        session.put("r1/tf", CASES["tf"][0].serialize())
        wait(lambda: robot.get_pose() is not None)
        x, y, yaw = robot.get_pose()  # type: ignore[misc]
        assert (x, y) == pytest.approx((2.5, 1.0)) and yaw == pytest.approx(2 * math.asin(0.1))
        assert robot.battery_soc == 1.0 and robot.errors == []
        session.put("r1/battery_state", CASES["battery state"][0].serialize())
        wait(lambda: robot.battery_soc != 1.0)
        assert robot.battery_soc == pytest.approx(0.75)
    finally:
        robot.close()
        server.close()


def wait(condition: Any, timeout: float = 5.0) -> None:
    import time

    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_the_action_client_sends_rmw_zenohs_requests(session: Any) -> None:
    """Against a stand-in rmw_zenoh service server: the key with the hash, a 33-byte attachment whose sequence goes
    up from 1 and whose GID is the XXH3-128 of the client's token, CDR payloads; the reply's attachment read back."""
    import zenoh

    asked: list[tuple[str, bytes, bytes]] = []
    jazzy = Interfaces("jazzy")

    def answer(query: Any) -> None:
        attachment_in = query.attachment.to_bytes()
        asked.append((str(query.key_expr), query.payload.to_bytes(), attachment_in))
        sequence, _, gid = read_attachment(attachment_in)
        response = jazzy.serialize(f"{NAV}_SendGoal_Response", {"accepted": True, "stamp": STAMP})
        query.reply(query.key_expr, response, attachment=attachment(sequence, gid))

    key = f"0/navigate_to_pose/_action/send_goal/{dds_type(NAV + '_SendGoal')}/{JAZZY_HASHES[NAV + '_SendGoal']}"
    queryable = session.declare_queryable(key, answer, complete=True)
    client = ActionClient(session, "jazzy")
    try:
        for n in (1, 2):
            goal_id, reply = client.send_goal(1.5, -2.0, 0.3, frame="map")
            assert reply.message["accepted"] is True and reply.sequence == n and reply.gid == client.gids["send_goal"]
            got_key, payload, raw = asked[-1]
            assert got_key == key
            request = jazzy.deserialize(f"{NAV}_SendGoal_Request", payload)
            assert bytes(request["goal_id"]["uuid"]) == goal_id
            assert request["goal"]["pose"]["header"]["frame_id"] == "map" and request["goal"]["behavior_tree"] == ""
            sequence, stamp, gid = read_attachment(raw)
            assert sequence == n and abs(stamp - time_ns()) < 5e9
            token = next(t for t in client.tokens_declared if "%send_goal/" in t)
            assert gid == xxhash.xxh3_128_intdigest(token.encode()).to_bytes(16, "little")
        assert isinstance(zenoh.QueryTarget.ALL_COMPLETE, zenoh.QueryTarget)
    finally:
        client.close()
        queryable.undeclare()


def time_ns() -> int:
    import time

    return time.time_ns()


def test_the_free_fleet_client_gives_up_on_a_robot_without_a_pose_as_free_fleet_does(session: Any) -> None:
    from free_fleet_client import FreeFleetRobot

    robot = FreeFleetRobot(session, "nobody", init_timeout_sec=1.5)
    try:
        with pytest.raises(RuntimeError, match=r"Timeout trying to initialize robot \[nobody\]"):
            robot.initialize()
        assert "does not exist" in robot.last_lookup_error or "same tree" in robot.last_lookup_error
    finally:
        robot.close()
