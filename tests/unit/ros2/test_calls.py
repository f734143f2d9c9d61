"""The node's services (:mod:`blackmetal.ros2.calls`): each call answered once, refusals in one sentence.

:class:`ServiceCalls` is driven here on its own, on a fake clock, with a
recorder for its output; the core around it, set_estop's confirmation by the
health and the parameter services are tests/unit/ros2/test_services.py and
test_parameters.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pytest

from blackmetal.robot_model import Encoders
from blackmetal.ros2.calls import ESTOP_REPEAT_S, MAX_PENDING_CALLS, ServiceCalls
from blackmetal.ros2.diagnostics import AdapterStats
from blackmetal.ros2.messages import RosCodec
from blackmetal.ros2.naming import attachment, parse_attachment
from blackmetal.ros2.options import Ros2Options
from blackmetal.ros2.ros_types import SET_BOOL, TRIGGER, Frames
from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import ErrorReport, EStop, Keys, encode, make_pose
from unit.ros2.test_services import encode_request

GID = bytes(range(16))


@pytest.fixture(scope="module")
def codec() -> RosCodec:
    return RosCodec()


@dataclass
class Out:
    """What the calls emit, and what the core's callbacks saw."""

    put: list[tuple[str, bytes]] = field(default_factory=list)
    queries: list[tuple[str, int, float]] = field(default_factory=list)
    replies: dict[int, tuple[bytes, bytes | None]] = field(default_factory=dict)
    refused: dict[int, str] = field(default_factory=dict)
    rejected: list[tuple[str, str]] = field(default_factory=list)
    follows: int = 0

    def ros(self, topic: str, cdr: bytes) -> None:
        raise AssertionError(f"nothing published on {topic} by these calls")

    def blackmetal(self, key: str, payload: bytes) -> None:
        self.put.append((key, payload))

    def error(self, message: ErrorReport) -> None:
        pass

    def service_reply(self, call: int, cdr: bytes, attachment: bytes | None) -> None:
        assert call not in self.replies and call not in self.refused, f"call {call} answered twice"
        self.replies[call] = (cdr, attachment)

    def service_refuse(self, call: int, reason: str) -> None:
        assert call not in self.replies and call not in self.refused, f"call {call} answered twice"
        self.refused[call] = reason

    def query(self, key: str, payload: bytes | None, tag: int, timeout: float) -> None:
        self.queries.append((key, tag, timeout))

    def follow(self, streams: frozenset[str]) -> None:
        pass


def service_calls(codec: RosCodec) -> tuple[ServiceCalls, Out]:
    out = Out()
    options = Ros2Options(Frames(), [0.0] * 36, [0.0] * 36, False, ("l", "r"), 0.1, Encoders(), service_keys={"set_estop": "0/set_estop/k"})

    def follow() -> None:
        out.follows += 1

    calls = ServiceCalls(
        options,
        Keys("r1"),
        out,
        codec,
        wallclock=lambda: 1_700_000_000.0,
        reporter=ErrorReporter("ros2", out.error),
        stats=AdapterStats(),
        follow=follow,
        reject=lambda key, reason, excerpt, now: out.rejected.append((key, reason)),
    )
    return calls, out


def answer(codec: RosCodec, out: Out, call: int, service: str = TRIGGER) -> tuple[bool, str]:
    response = codec.decode(out.replies[call][0], f"{service}_Response")
    return response.success, response.message


def test_a_service_the_node_does_not_have_is_refused_with_its_name(codec: RosCodec) -> None:
    calls, out = service_calls(codec)
    calls.on_service_request("spin", 1, b"", None, now=0.0)
    assert out.refused == {1: "no service 'spin' here"} and calls.pending == {}


def test_an_attachment_with_a_negative_sequence_number_is_refused_and_reported_on_the_services_key(codec: RosCodec) -> None:
    calls, out = service_calls(codec)
    request = encode_request(codec, SET_BOOL, data=True)
    calls.on_service_request("set_estop", 1, request, attachment(-1, 0, GID), now=0.0)
    assert out.refused[1].startswith("service request with an attachment that is not rmw_zenoh's: sequence number -1")
    assert out.rejected == [("0/set_estop/k", out.refused[1])] and out.put == [] and calls.stats.failed.total == 1


def test_a_set_estop_is_put_again_until_its_deadline_and_the_health_is_followed_meanwhile(codec: RosCodec) -> None:
    calls, out = service_calls(codec)
    calls.on_service_request("set_estop", 7, encode_request(codec, SET_BOOL, data=True), attachment(3, 0, GID), now=0.0)
    assert out.put == [("r1/estop", encode(EStop(engaged=True)))] and out.queries[0][0] == "r1/gateway/health"
    assert calls.waits_for_health and out.follows == 1
    assert calls.next_deadline() == ESTOP_REPEAT_S
    calls.tick(ESTOP_REPEAT_S)
    assert len(out.put) == 2 and calls.next_deadline() == pytest.approx(2 * ESTOP_REPEAT_S)
    calls.tick(calls.options.service_timeout)
    success, message = answer(codec, out, 7, SET_BOOL)
    assert not success and message.startswith("the gateway did not confirm the e-stop on within 2 s")
    assert parse_attachment(out.replies[7][1] or b"") == (3, 1_700_000_000 * 10**9, GID)  # the request's id, our time
    assert not calls.waits_for_health and out.follows == 2 and calls.next_deadline() == math.inf


def test_more_calls_than_can_wait_are_answered_false_at_once(codec: RosCodec) -> None:
    calls, out = service_calls(codec)
    for call in range(MAX_PENDING_CALLS + 1):
        calls.on_service_request("reset_odometry", call, encode_request(codec, TRIGGER), None, now=0.0)
    assert len(calls.pending) == MAX_PENDING_CALLS and list(out.replies) == [MAX_PENDING_CALLS]
    assert answer(codec, out, MAX_PENDING_CALLS) == (
        False,
        f"{MAX_PENDING_CALLS} calls are already waiting for their confirmation; call again",
    )
    assert calls.stats.failed.total == 1


@pytest.mark.parametrize(
    ("ok", "payload", "message"),
    [
        (True, encode(make_pose(1.0, 0.5, 0.0, 0.25)), "the odometry answered x=0.5 y=0 yaw=0.25 after the reset"),
        (True, b"{}", "the odometry answered something that is not a pose: "),
        (False, b"busy", "the odometry refused the reset: busy"),
    ],
)
def test_a_reset_is_true_only_when_the_odometry_answers_the_origin(codec: RosCodec, ok: bool, payload: bytes, message: str) -> None:
    calls, out = service_calls(codec)
    calls.on_service_request("reset_odometry", 1, encode_request(codec, TRIGGER), None, now=0.0)
    (key, tag, timeout), *_ = out.queries
    assert (key, timeout) == ("r1/odometry/reset", 2.0)
    calls.on_query_reply(tag, ok, payload, now=0.1)
    success, text = answer(codec, out, 1)
    assert not success and text.startswith(message)
    calls.on_query_done(tag, now=0.1)  # the end of the replies answers nothing again
    assert calls.stats.confirmed == 0 and calls.stats.failed.total == 1


def test_a_malformed_request_is_answered_false_with_the_reason_and_puts_nothing(codec: RosCodec) -> None:
    calls, out = service_calls(codec)
    calls.on_service_request("reset_odometry", 1, b"\x00\x01", None, now=0.0)
    success, message = answer(codec, out, 1)
    assert not success and message.startswith("invalid request: invalid Trigger_Request: 2 bytes: a CDR message starts with")
    assert out.queries == [] and out.put == [] and out.rejected[0][0] == "reset_odometry"  # no key configured: its name
