"""The messages (:mod:`blackmetal.schemas.messages`): each goes through the codec and back, bounds are refused.

Inputs from any client (Twist, EStop, Lock, PoseReset, ParamsSet, SimFaults)
refuse unknown fields; messages between our own services tolerate them, so a
newer publisher does not break an older subscriber. What a client sends as
a Twist, and the finite floats of poses and impulses, are
tests/unit/schemas/test_codec.py's.
"""

from __future__ import annotations

import json
import math

import msgspec
import pytest

from blackmetal.schemas import MESSAGE_TYPES, PayloadError, decode, encode
from blackmetal.schemas import messages as m
from blackmetal.schemas import navigation as n
from blackmetal.schemas import wheels as wh

GOAL_ID = "0123456789abcdef0123456789abcdef"
PARAMS = m.GatewayParams(
    stamp=5.0, params=[m.Param("max_speed", "double", 0.5, min=0.0, max=1.0), m.Param("name", "string", "r1", read_only=True)]
)
#: One message of every type, with its optional fields set: what travels on the keys.
EXAMPLES: dict[str, msgspec.Struct] = {
    "Twist": m.Twist(linear=m.Vector3(x=0.2), angular=m.Vector3(z=-1.0)),
    "EStop": m.EStop(engaged=True),
    "Lock": m.Lock(locked=False),
    "WheelImpulses": m.WheelImpulses(seq=7, stamp=1_700_000_000.5, left=120, right=-118, mono=12.25, source="run1"),
    "Pose": m.make_pose(1_700_000_000.5, 1.0, -2.0, 3.0, v=0.1, w=0.2),
    "RobotStatus": m.RobotStatus(stamp=1.0, state=3, state_name="RUN", direction=1, direction_name="NORTH"),
    "GatewayHealth": m.GatewayHealth(
        stamp=1.0,
        control=m.LinkHealth("connected", connected_since=0.5),
        log=m.LinkHealth("down", reconnects=2, reason="refused"),
        estop=True,
        estop_since=0.75,
        estop_by="r1/estop",
        wheel_speeds=(0.1, -0.1),
        sources={"nav": m.SourceHealth(priority=10, age=0.1)},
        locks={"dock": True},
    ),
    "ErrorReport": m.ErrorReport(stamp=1.0, source="gateway", key="r1/cmd_vel", reason="bad", excerpt="{", suppressed=3),
    "DriverChange": m.DriverChange(stamp=1.0, source="nav", previous=None, reason="first command"),
    "SimFaults": m.SimFaults(dropout=0.5, delay=1.0, silent=True),
    "PoseReset": m.PoseReset(x=1.0, yaw=-0.5),
    "GatewayParams": PARAMS,
    "ParamsSet": m.ParamsSet(values={"max_speed": 0.4, "telemetry": True, "poll_hz": 25, "name": "r2"}),
    "ParamsSetReply": m.ParamsSetReply(
        results=[m.ParamResult("max_speed", True), m.ParamResult("x", False, "no such parameter")], params=PARAMS
    ),
    "NavGoal": n.NavGoal(x=1.0, y=-2.0, yaw=0.5, frame="odom", goal_id=GOAL_ID),
    "NavMove": n.NavMove(distance=-0.5, goal_id=GOAL_ID),
    "NavGoalReply": n.NavGoalReply(accepted=False, goal_id=GOAL_ID, reason="the robot is e-stopped"),
    "NavCancel": n.NavCancel(goal_id=GOAL_ID),
    "NavCancelReply": n.NavCancelReply(canceled=[GOAL_ID], reason=""),
    "NavFeedback": n.NavFeedback(
        stamp=1.0,
        goal_id=GOAL_ID,
        state=n.GoalState.ABORTED,
        pose=n.PlanarPose(0.1, 0.2, 0.3),
        goal=n.PlanarPose(1.0, 2.0, 3.0, frame="odom"),
        distance_remaining=2.0,
        eta=4.5,
        elapsed=1.5,
        recoveries=0,
        reason="e-stop engaged",
    ),
    "NavResultQuery": n.NavResultQuery(goal_id=GOAL_ID),
    "NavResult": n.NavResult(
        found=True,
        goal_id=GOAL_ID,
        state=n.GoalState.SUCCEEDED,
        pose=n.PlanarPose(1.0, 2.0, 0.0),
        goal=n.PlanarPose(1.0, 2.0, 0.0),
        elapsed=3.0,
    ),
    "MapPose": n.MapPose(stamp=1.0, x=10.0, y=-5.0, yaw=1.5, map="site", by="r1/nav/set_pose"),
    "SetPose": n.SetPose(x=1.0, y=2.0, yaw=0.1),
    "WheelMove": wh.WheelMove(left=0.5, right=-0.5, source="nav", move_id=GOAL_ID),
    "WheelMoveReply": wh.WheelMoveReply(
        accepted=True, move_id=GOAL_ID, left_impulses=506, right_impulses=-527, expected=1.67, deadline=3.5
    ),
    "WheelPosition": wh.WheelPosition(
        stamp=1_700_000_000.5,
        move_id=GOAL_ID,
        source="nav",
        state=wh.MoveState.RUNNING,
        left=120,
        right=-118,
        start_left=0,
        start_right=0,
        target_left=506,
        target_right=527,
        elapsed=0.4,
    ),
}


def test_there_is_an_example_of_every_message() -> None:
    assert set(EXAMPLES) == set(MESSAGE_TYPES)
    assert all(type(EXAMPLES[name]) is kind for name, kind in MESSAGE_TYPES.items())


@pytest.mark.parametrize("name", sorted(MESSAGE_TYPES))
def test_every_message_goes_through_the_codec_and_back(name: str) -> None:
    message = EXAMPLES[name]
    assert decode(MESSAGE_TYPES[name], encode(message)) == message


def test_a_parameter_value_keeps_its_json_type() -> None:
    values = decode(m.ParamsSet, encode(EXAMPLES["ParamsSet"])).values
    assert [type(v) for v in values.values()] == [float, bool, int, str]  # a bool is no int, an int no float
    assert json.loads(encode(m.Param("poll_hz", "integer", 50))) == {"name": "poll_hz", "type": "integer", "value": 50}  # defaults left out


@pytest.mark.parametrize(
    ("kind", "payload", "reason"),
    [
        (m.WheelImpulses, b'{"seq":-1,"stamp":1,"left":0,"right":0}', "Expected `int` >= 0 - at `$.seq`"),
        (m.WheelImpulses, json.dumps({"seq": 0, "stamp": 1, "left": 0, "right": 0, "source": "s" * 65}).encode(), "length <= 64"),
        (m.SimFaults, b'{"dropout":1.5}', "Expected `float` <= 1.0 - at `$.dropout`"),
        (m.SimFaults, b'{"spike":-0.1}', "Expected `float` >= 0.0 - at `$.spike`"),
        (m.SimFaults, b'{"delay":61}', "Expected `float` <= 60.0 - at `$.delay`"),
        (m.EStop, b"{}", "Object missing required field `engaged`"),
        (m.EStop, b'{"engaged":"yes"}', "Expected `bool`, got `str`"),
        (m.PoseReset, b'{"x":1e999}', "number out of range (not finite) - at `$.x`"),
    ],
)
def test_values_out_of_bounds_are_refused_with_where(kind: type[msgspec.Struct], payload: bytes, reason: str) -> None:
    with pytest.raises(PayloadError) as refused:
        decode(kind, payload)
    assert reason in str(refused.value)


@pytest.mark.parametrize("name", ["Twist", "EStop", "Lock", "PoseReset", "ParamsSet", "SimFaults"])
def test_what_any_client_sends_refuses_a_field_it_does_not_know(name: str) -> None:
    payload = json.loads(encode(EXAMPLES[name]))
    with pytest.raises(PayloadError, match="unknown field `typo`"):
        decode(MESSAGE_TYPES[name], json.dumps({**payload, "typo": 1}).encode())


@pytest.mark.parametrize(
    "name", ["WheelImpulses", "Pose", "GatewayHealth", "ErrorReport", "DriverChange", "GatewayParams", "ParamsSetReply"]
)
def test_what_our_services_publish_tolerates_a_newer_publishers_fields(name: str) -> None:
    payload = json.loads(encode(EXAMPLES[name]))
    assert decode(MESSAGE_TYPES[name], json.dumps({**payload, "added_later": [1]}).encode()) == EXAMPLES[name]


@pytest.mark.parametrize(
    ("stamp", "parts"),
    [(1_700_000_000.25, (1_700_000_000, 250_000_000)), (0.0, (0, 0)), (1.9999999999, (2, 0)), (-0.5, (-1, 500_000_000))],
)
def test_a_stamp_is_whole_seconds_and_nanoseconds_below_one_second(stamp: float, parts: tuple[int, int]) -> None:
    assert m.stamp_parts(stamp) == parts


def test_the_estop_says_since_when_and_by_whom_in_utc() -> None:
    health = EXAMPLES["GatewayHealth"]
    assert isinstance(health, m.GatewayHealth)
    assert health.estop_origin() == " since 1970-01-01 00:00:00 UTC by r1/estop"
    assert m.GatewayHealth(stamp=0.0, control=m.LinkHealth("down"), log=m.LinkHealth("down"), estop_since=86_400.0).estop_origin() == (
        " since 1970-01-02 00:00:00 UTC by unknown"
    )
    assert m.GatewayHealth(stamp=0.0, control=m.LinkHealth("down"), log=m.LinkHealth("down"), estop=True).estop_origin() == ""


def test_a_vector_refuses_what_is_not_finite_and_names_it() -> None:
    with pytest.raises(ValueError, match=r"vector\.y must be a finite number, got nan"):
        m.Vector3(y=math.nan)
