"""The ROS 2 node's parameters (issue #28): rclcpp's parameter services answered from the gateway's table, sets sent to
the gateway's key and answered with its results, /parameter_events. The core on a fake clock; no Zenoh."""

from __future__ import annotations

import json
from typing import Any

import pytest

from blackmetal.ros2.messages import RosCodec
from blackmetal.ros2.naming import PARAMETER_EVENTS, PARAMETER_SERVICES, attachment, parse_attachment
from blackmetal.ros2.parameters import list_names
from blackmetal.ros2.ros_types import (
    DESCRIBE_PARAMETERS,
    GET_PARAMETER_TYPES,
    GET_PARAMETERS,
    LIST_PARAMETERS,
    PARAMETER_EVENT,
    SET_PARAMETERS,
    SET_PARAMETERS_ATOMICALLY,
    ParameterType,
)
from blackmetal.schemas import GatewayParams, Param, ParamResult, ParamsSet, ParamsSetReply, decode, encode
from unit.ros2.test_services import PARAMETER_EVENT_HASH, PARAMETER_SERVICE_HASHES, encode_request, make_core

GID = bytes(range(16))
TABLE = GatewayParams(
    stamp=1.0,
    params=[
        Param("max_wheel_speed", "double", 0.8, "per-wheel speed limit", min=0.01, max=0.8),
        Param("sources.nav.priority", "integer", 10, "priority of nav", min=0, max=255),
        Param("wheel_radius", "double", 0.1, "wheel radius", read_only=True),
        Param("release_key_only", "bool", False, read_only=True),
        Param("robot", "string", "127.0.0.1", read_only=True),
    ],
)


@pytest.fixture(scope="module")
def codec() -> RosCodec:
    return RosCodec()


def test_the_services_and_the_event_have_ros_2s_own_type_hashes(codec: RosCodec) -> None:
    for name, (type_name, type_hash) in PARAMETER_SERVICE_HASHES.items():
        assert PARAMETER_SERVICES[name] == f"rcl_interfaces/srv/{type_name}"
        assert codec.type_hash(PARAMETER_SERVICES[name]) == type_hash, name
    assert codec.type_hash(PARAMETER_EVENT) == PARAMETER_EVENT_HASH


def test_list_selects_by_prefix_and_depth_as_rclcpp_does() -> None:
    names = ["a", "b.c", "b.d.e", "f.g"]
    assert list_names(names, [], 0) == (names, ["b", "b.d", "f"])
    assert list_names(names, [], 1) == (["a"], [])  # depth 1: no separator in the name
    assert list_names(names, ["b"], 0) == (["b.c", "b.d.e"], ["b", "b.d"])
    assert list_names(names, ["b"], 1) == ([], [])  # rclcpp counts the separator after the prefix: ".c" has one
    assert list_names(names, ["b"], 2) == (["b.c"], ["b"])
    assert list_names(["z", "a.b", "m"], [], 0) == (["a.b", "m", "z"], ["a"])  # in name order, as rclcpp's std::map
    assert list_names(names, ["a", "f"], 0) == (["a", "f.g"], ["f"])
    assert list_names(names, ["b.d.e"], 1) == (["b.d.e"], ["b.d"])  # the name itself matches its prefix
    assert list_names(names, ["x"], 0) == ([], [])


def call(core: Any, service: str, cdr: bytes, number: int, now: float = 1.0) -> None:
    core.calls.on_service_request(service, number, cdr, attachment(number, 5, GID), now=now)


def with_table(codec: RosCodec) -> tuple[Any, Any]:
    core, out = make_core(codec)
    core.calls.on_params(encode(TABLE), now=0.5)
    return core, out


def test_the_table_is_asked_at_the_start_and_again_when_the_gateway_comes_back(codec: RosCodec) -> None:
    core, out = make_core(codec)
    core.start()
    assert [q[0] for q in out.queries if "/nav/" not in q[0]] == ["robot/gateway/params"]
    core.on_query_reply(out.queries[0][2], True, encode(TABLE), now=0.1)
    assert "max_wheel_speed" in core.parameters.table
    core.on_alive("gateway", False, now=1.0)
    core.on_alive("gateway", True, now=2.0)
    assert [q[0] for q in out.queries if "/nav/" not in q[0]] == ["robot/gateway/params"] * 2


def test_the_first_table_is_new_parameters_and_a_change_is_changed_parameters(codec: RosCodec) -> None:
    core, out = with_table(codec)
    (topic, cdr), *_ = out.ros_out
    event = codec.decode(cdr, PARAMETER_EVENT)
    assert topic == PARAMETER_EVENTS and event.node == "/blackmetal" and not event.changed_parameters
    assert [p.name for p in event.new_parameters] == [p.name for p in TABLE.params]
    speed = event.new_parameters[0].value
    assert (speed.type, speed.double_value) == (ParameterType.DOUBLE, 0.8)
    core.calls.on_params(encode(TABLE), now=1.0)  # the same table again: nothing to say
    assert len(out.ros_out) == 1
    changed = GatewayParams(stamp=2.0, params=[Param("max_wheel_speed", "double", 0.3, min=0.01, max=0.8)], changed=["max_wheel_speed"])
    core.calls.on_params(encode(changed), now=2.0)
    event = codec.decode(out.ros_out[-1][1], PARAMETER_EVENT)
    assert [(p.name, p.value.double_value) for p in event.changed_parameters] == [("max_wheel_speed", 0.3)]
    assert not event.new_parameters


def test_list_get_types_and_describe_are_answered_from_the_table_at_once(codec: RosCodec) -> None:
    core, out = with_table(codec)
    call(core, "list_parameters", encode_request(codec, LIST_PARAMETERS, prefixes=[], depth=0), 1)
    listed = codec.decode(out.replies[1][0], f"{LIST_PARAMETERS}_Response").result
    assert listed.names == sorted(p.name for p in TABLE.params) and listed.prefixes == ["sources.nav"]
    assert parse_attachment(out.replies[1][1] or b"")[0] == 1 and out.queries == []  # the request's id; nothing asked

    call(core, "get_parameters", encode_request(codec, GET_PARAMETERS, names=["sources.nav.priority", "nope", "robot"]), 2)
    values = codec.decode(out.replies[2][0], f"{GET_PARAMETERS}_Response").values
    assert [(v.type, v.integer_value, v.string_value) for v in values] == [(2, 10, ""), (0, 0, ""), (4, 0, "127.0.0.1")]

    call(core, "get_parameter_types", encode_request(codec, GET_PARAMETER_TYPES, names=["release_key_only", "nope"]), 3)
    assert list(codec.decode(out.replies[3][0], f"{GET_PARAMETER_TYPES}_Response").types) == [1, 0]

    call(core, "describe_parameters", encode_request(codec, DESCRIBE_PARAMETERS, names=["max_wheel_speed", "sources.nav.priority"]), 4)
    speed, priority = codec.decode(out.replies[4][0], f"{DESCRIBE_PARAMETERS}_Response").descriptors
    assert (speed.type, speed.read_only, speed.description) == (3, False, "per-wheel speed limit")
    assert [(r.from_value, r.to_value) for r in speed.floating_point_range] == [(0.01, 0.8)] and not speed.integer_range
    assert [(r.from_value, r.to_value) for r in priority.integer_range] == [(0, 255)]


def test_a_call_before_the_gateways_table_waits_for_it_or_says_why_it_never_came(codec: RosCodec) -> None:
    core, out = make_core(codec)
    core.start()  # asks the gateway's table; the answer is not in yet (a node that has just started)
    call(core, "list_parameters", encode_request(codec, LIST_PARAMETERS, prefixes=[], depth=0), 1, now=0.1)
    assert out.replies == {} and out.refused == {}  # not an empty list: it waits for the table
    assert [q[0] for q in out.queries if "/nav/" not in q[0]] == ["robot/gateway/params"] * 2  # and asks for it again
    core.on_query_reply(out.queries[-1][2], True, encode(TABLE), now=0.2)
    listed = codec.decode(out.replies[1][0], f"{LIST_PARAMETERS}_Response").result
    assert listed.names == sorted(p.name for p in TABLE.params)

    late, late_out = make_core(codec)
    call(late, "get_parameters", encode_request(codec, GET_PARAMETERS, names=["max_wheel_speed"]), 7, now=1.0)
    late.tick(1.0 + late.options.service_timeout)  # no gateway ever answers
    assert late_out.replies == {} and "parameters did not arrive" in late_out.refused[7] and "prefix robot" in late_out.refused[7]


def results(codec: RosCodec, cdr: bytes) -> list[tuple[bool, str]]:
    return [(r.successful, r.reason) for r in codec.decode(cdr, f"{SET_PARAMETERS}_Response").results]


def test_a_set_goes_to_the_gateways_key_and_is_answered_with_its_results(codec: RosCodec) -> None:
    core, out = with_table(codec)
    # an integer for a double parameter is that double (``ros2 param set /blackmetal max_wheel_speed 1``)
    request = encode_request(codec, SET_PARAMETERS, parameters=[("max_wheel_speed", 1), ("sources.nav.priority", 50)])
    call(core, "set_parameters", request, 7)
    ((key, payload, tag, _),) = out.queries
    assert key == "robot/gateway/params/set" and 7 not in out.replies
    sent = decode(ParamsSet, payload or b"")
    assert sent.values == {"max_wheel_speed": 1.0, "sources.nav.priority": 50} and isinstance(sent.values["max_wheel_speed"], float)
    after = GatewayParams(
        stamp=2.0, params=[Param("sources.nav.priority", "integer", 50, min=0, max=255)], changed=["sources.nav.priority"]
    )
    reply = ParamsSetReply(
        results=[
            ParamResult("max_wheel_speed", False, "max_wheel_speed must be within 0.01..0.8, got 1.0"),
            ParamResult("sources.nav.priority", True),
        ],
        params=after,
    )
    core.on_query_reply(tag, True, encode(reply), now=1.01)
    assert results(codec, out.replies[7][0]) == [(False, "max_wheel_speed must be within 0.01..0.8, got 1.0"), (True, "")]
    assert parse_attachment(out.replies[7][1] or b"")[0] == 7
    event = codec.decode(out.ros_out[-1][1], PARAMETER_EVENT)  # the change is on /parameter_events at once
    assert [(p.name, p.value.integer_value) for p in event.changed_parameters] == [("sources.nav.priority", 50)]
    core.calls.on_query_done(tag, now=1.02)  # the query ends after its reply: nothing more
    assert len(out.replies) == 1 and core.calls.pending == {}


def test_arrays_and_unsetting_are_refused_here_and_never_reach_the_gateway(codec: RosCodec) -> None:
    core, out = with_table(codec)
    t = codec.store.types
    value = t["rcl_interfaces/msg/ParameterValue"]
    array = codec._value(1.0)
    array.type, array.double_array_value = int(ParameterType.DOUBLE_ARRAY), __import__("numpy").asarray([1.0])
    unset = codec._value(None)
    request = codec.store.types[f"{SET_PARAMETERS}_Request"](
        parameters=[
            t["rcl_interfaces/msg/Parameter"](name="max_wheel_speed", value=array),
            t["rcl_interfaces/msg/Parameter"](name="robot", value=unset),
        ]
    )
    assert isinstance(request.parameters[0].value, value)
    call(core, "set_parameters", bytes(codec.store.serialize_cdr(request, f"{SET_PARAMETERS}_Request")), 1)
    assert out.queries == []  # nothing asked of the gateway
    (array_result, unset_result) = results(codec, out.replies[1][0])
    assert not array_result[0] and "double_array values are refused" in array_result[1]
    assert not unset_result[0] and "cannot be unset" in unset_result[1]
    assert len(out.errors) == 2 and all("set_parameters" in e.reason for e in out.errors)  # reported on errors too


def test_an_atomic_set_with_one_bad_value_sets_none(codec: RosCodec) -> None:
    core, out = with_table(codec)
    bad = encode_request(codec, SET_PARAMETERS_ATOMICALLY, parameters=[("max_wheel_speed", 0.5), ("wheel_radius", 0.2)])
    call(core, "set_parameters_atomically", bad, 1)
    assert out.queries == []
    result = codec.decode(out.replies[1][0], f"{SET_PARAMETERS_ATOMICALLY}_Response").result
    assert not result.successful and "wheel_radius is read-only" in result.reason
    good = encode_request(codec, SET_PARAMETERS_ATOMICALLY, parameters=[("max_wheel_speed", 0.5), ("sources.nav.priority", 20)])
    call(core, "set_parameters_atomically", good, 2)
    ((_, payload, tag, _),) = out.queries
    assert decode(ParamsSet, payload or b"").values == {"max_wheel_speed": 0.5, "sources.nav.priority": 20}
    reply = ParamsSetReply(results=[ParamResult("max_wheel_speed", True), ParamResult("sources.nav.priority", True)], params=TABLE)
    core.on_query_reply(tag, True, encode(reply), now=1.1)
    result = codec.decode(out.replies[2][0], f"{SET_PARAMETERS_ATOMICALLY}_Response").result
    assert result.successful and result.reason == ""


def test_a_set_nobody_answers_fails_with_what_to_check(codec: RosCodec) -> None:
    core, out = with_table(codec)
    call(core, "set_parameters", encode_request(codec, SET_PARAMETERS, parameters=[("max_wheel_speed", 0.5)]), 1)
    core.calls.on_query_done(out.queries[0][2], now=1.5)
    ((ok, reason),) = results(codec, out.replies[1][0])
    assert not ok and "no gateway answered on robot/gateway/params/set" in reason and "nothing was set" in reason

    call(core, "set_parameters", encode_request(codec, SET_PARAMETERS, parameters=[("max_wheel_speed", 0.5)]), 2, now=2.0)
    core.tick(4.0)  # the service timeout (2 s) passes without an answer or the query's end
    ((ok, reason),) = results(codec, out.replies[2][0])
    assert not ok and "did not answer within 2 s" in reason

    call(core, "set_parameters", encode_request(codec, SET_PARAMETERS, parameters=[("max_wheel_speed", 0.5)]), 3, now=5.0)
    core.on_query_reply(out.queries[-1][2], False, b"not allowed", now=5.1)  # an error reply (the router's ACL, a bad payload)
    ((ok, reason),) = results(codec, out.replies[3][0])
    assert not ok and "refused the set: not allowed" in reason


def test_a_request_that_is_not_cdr_is_refused_and_reported(codec: RosCodec) -> None:
    core, out = with_table(codec)
    call(core, "get_parameters", b"\x00\x01\x00\x00\xff\xff\xff\x7f", 1)
    assert 1 in out.refused and "invalid request" in out.refused[1] and out.replies == {}
    assert out.errors and "GetParameters_Request" in out.errors[-1].reason


def test_gateway_param_payloads_that_do_not_decode_are_reported(codec: RosCodec) -> None:
    core, out = make_core(codec)
    core.calls.on_params(json.dumps({"stamp": 1.0}).encode(), now=1.0)
    assert out.errors and out.errors[-1].key == "robot/gateway/params" and out.ros_out == []
