"""Wire codec: exact bytes for every command; framing that survives split, glued and garbage streams."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from blackmetal import wire
from blackmetal.wire import (
    CommandCode,
    LogReport,
    Malformed,
    PositionReading,
    ProtocolError,
    ReplyDecoder,
    Request,
    RequestDecoder,
    SpeedReading,
    StatusReply,
    encode_request,
)


@pytest.mark.parametrize(
    "request_, wire",
    [
        (wire.simple(CommandCode.EMPTY), b'{"UserID":1,"Command":0}'),
        (wire.simple(CommandCode.EMG_STOP), b'{"UserID":1,"Command":1}'),
        (wire.simple(CommandCode.NORMAL_STOP), b'{"UserID":1,"Command":2}'),
        (
            wire.set_velocity(left=0.25, right=0.25),
            b'{"UserID":1,"Command":3,"RightWheelSpeed":0.250000,"LeftWheelSpeed":0.250000}',
        ),
        (
            wire.set_velocity(left=0.1234567, right=-0.8),
            b'{"UserID":1,"Command":3,"RightWheelSpeed":-0.800000,"LeftWheelSpeed":0.123457}',
        ),
        (
            wire.set_velocity(left=-1e-9, right=-0.0),
            b'{"UserID":1,"Command":3,"RightWheelSpeed":0.000000,"LeftWheelSpeed":0.000000}',
        ),
        (
            Request(CommandCode.SET_LR_WHEEL_POSITION, left=-1200, right=1200),
            b'{"UserID":1,"Command":4,"RightWheelPosition":1200,"LeftWheelPosition":-1200}',
        ),
        (wire.simple(CommandCode.NOT_IMPLEMENTED_5), b'{"UserID":1,"Command":5}'),
        (wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY), b'{"UserID":1,"Command":6}'),
        (wire.simple(CommandCode.PREPARE_WHEEL_CONTROLLER), b'{"UserID":1,"Command":7}'),
        (wire.simple(CommandCode.GET_LR_WHEEL_POSITION), b'{"UserID":1,"Command":8}'),
    ],
)
def test_every_command_encodes_to_the_robots_bytes(request_: Request, wire: bytes) -> None:
    assert encode_request(request_) == wire
    # and the simulator's side reads it back
    (decoded,) = RequestDecoder().feed(wire)
    assert isinstance(decoded, Request)
    assert decoded.command == request_.command


@pytest.mark.parametrize(
    "right, left",
    [(math.nan, 0.0), (0.0, math.inf), (-math.inf, 0.0), (1.0001, 0.0), (0.0, -5.0), (True, 0.0), ("0.1", 0.0)],
)
def test_velocity_the_robot_must_never_see_is_refused(right: object, left: object) -> None:
    with pytest.raises(ProtocolError):
        encode_request(Request(CommandCode.SET_LR_WHEEL_VELOCITY, left=left, right=right))  # type: ignore[arg-type]


@pytest.mark.parametrize("value", [2**31, -(2**31) - 1, 1.5, None])
def test_positions_must_be_32_bit_integers(value: object) -> None:
    with pytest.raises(ProtocolError):
        encode_request(Request(CommandCode.SET_LR_WHEEL_POSITION, left=0, right=value))  # type: ignore[arg-type]


def test_only_the_gets_expect_a_data_reply() -> None:
    assert CommandCode.GET_LR_WHEEL_VELOCITY in wire.DATA_COMMANDS
    assert CommandCode.GET_LR_WHEEL_POSITION in wire.DATA_COMMANDS
    assert CommandCode.SET_LR_WHEEL_VELOCITY not in wire.DATA_COMMANDS


@pytest.mark.parametrize(
    "wire, reply",
    [
        (b'{"status":"RECIEVE_OK"}', StatusReply("RECIEVE_OK")),
        (b'{"status":"FULL_BUFFER"}', StatusReply("FULL_BUFFER")),
        (b'{"status": "RECIEVE_OK" }', StatusReply("RECIEVE_OK")),
        (b'{"LeftWheelSpeed"=150 "RightWheelSpeed"=-148}', SpeedReading(left=150, right=-148)),
        (b'{"LeftWheelSpeed"=150,"RightWheelSpeed"=-148}', SpeedReading(left=150, right=-148)),
        (b'{"RightWheelSpeed"=-1, "LeftWheelSpeed"=0}', SpeedReading(left=0, right=-1)),
        (b'{"LeftWheelSpeed":150,"RightWheelSpeed":-148}', SpeedReading(left=150, right=-148)),
        (b'{"LeftWheelPosition"=1200 "RightWheelPosition"=-1190}', PositionReading(left=1200, right=-1190)),
        (b'{"state":1,"direction":1}', LogReport(1, 1)),
        (b'{"state":3, "direction":4}', LogReport(3, 4)),
    ],
)
def test_each_reply_decodes(wire: bytes, reply: object) -> None:
    decoder = ReplyDecoder()
    assert decoder.feed(wire) == [reply]
    assert decoder.malformed == 0 and decoder.garbage_bytes == 0


def test_status_flags() -> None:
    assert StatusReply("RECIEVE_OK").ok and not StatusReply("RECIEVE_OK").full_buffer
    assert StatusReply("FULL_BUFFER").full_buffer and not StatusReply("FULL_BUFFER").ok


@pytest.mark.parametrize(
    "wire",
    [
        b'{"LeftWheelSpeed"=1.5 "RightWheelSpeed"=2}',
        b'{"LeftWheelSpeed"=99999999999 "RightWheelSpeed"=2}',
        b'{"LeftWheelSpeed"=1}',
        b'{"LeftWheelSpeed"=1 "RightWheelSpeed"=2 "Extra"=3}',
        b'{"LeftWheelSpeed"=1 "LeftWheelSpeed"=2}',
        b'{"status":""}',
        b'{"status":1}',
        b'{"state":"READY","direction":1}',
        b"{}",
        b"{garbage}",
        b'{"LeftWheelSpeed"=NaN "RightWheelSpeed"=2}',
    ],
)
def test_malformed_frames_are_reported_not_raised(wire: bytes) -> None:
    decoder = ReplyDecoder()
    (item,) = decoder.feed(wire)
    assert isinstance(item, Malformed)
    assert item.reason
    assert decoder.malformed == 1


def test_glued_split_and_garbage_stream() -> None:
    decoder = ReplyDecoder()
    out = decoder.feed(b'\x00\xffjunk{"status":"RECIEVE_OK"}{"LeftWheelSpeed"=150 "Right')
    assert out[0] == Malformed("bytes outside any {...} message", b"\x00\xffjunk")
    assert out[1:] == [StatusReply("RECIEVE_OK")]
    assert decoder.pending > 0
    out = decoder.feed(b'WheelSpeed"=-148}  {"stat')
    assert out == [SpeedReading(left=150, right=-148)]
    out = decoder.feed(b'us":"FULL_BUFFER"}}}{"state":1,"direction":1}')
    assert out == [StatusReply("FULL_BUFFER"), Malformed("bytes outside any {...} message", b"}}"), LogReport(1, 1)]
    assert decoder.garbage_bytes == len(b"\x00\xffjunk") + 2
    assert decoder.malformed == 2
    assert decoder.pending == 0


def test_resynchronises_on_a_message_cut_by_a_new_one() -> None:
    decoder = ReplyDecoder()
    out = decoder.feed(b'{"LeftWheelSp{"status":"RECIEVE_OK"}')
    assert isinstance(out[0], Malformed)
    assert out[1] == StatusReply("RECIEVE_OK")


def test_unbounded_garbage_without_a_closing_brace_keeps_the_buffer_bounded() -> None:
    decoder = ReplyDecoder(max_frame=512)
    for _ in range(1000):
        decoder.feed(b"{" + b"A" * 1000)
        assert decoder.pending <= 512 + 1001
    assert decoder.feed(b'{"status":"RECIEVE_OK"}')[-1] == StatusReply("RECIEVE_OK")
    assert decoder.pending == 0
    assert decoder.garbage_bytes > 900_000


def test_reset_forgets_a_partial_message() -> None:
    decoder = ReplyDecoder()
    decoder.feed(b'{"status":"RECIE')
    decoder.reset()
    assert decoder.feed(b'{"status":"RECIEVE_OK"}') == [StatusReply("RECIEVE_OK")]


def test_request_decoder_rejects_what_a_robot_must_not_act_on() -> None:
    decoder = RequestDecoder()
    items = decoder.feed(
        b'{"UserID":1,"Command":3,"RightWheelSpeed":NaN,"LeftWheelSpeed":0}'
        b'{"UserID":1,"Command":9}'
        b'{"Command":6}'
        b'{"UserID":1,"Command":3,"RightWheelSpeed":"x","LeftWheelSpeed":0}'
        b'{"UserID":1,"Command":4,"RightWheelPosition":1.5,"LeftWheelPosition":0}'
        b'{"UserID":1,"Command":6}'
    )
    assert [type(item) for item in items] == [Malformed] * 5 + [Request]
    assert decoder.malformed == 5


def test_reply_encoders_match_the_robots_format() -> None:
    assert wire.encode_status() == b'{"status":"RECIEVE_OK"}'
    assert wire.encode_wheel_speeds(left=150, right=-148) == b'{"LeftWheelSpeed"=150 "RightWheelSpeed"=-148}'
    assert wire.encode_wheel_speeds(left=150, right=-148, separator=",") == b'{"LeftWheelSpeed"=150,"RightWheelSpeed"=-148}'
    assert wire.encode_log_report(1, 1) == b'{"state":1,"direction":1}'
    with pytest.raises(ProtocolError):
        wire.encode_wheel_speeds(left=1, right=1, separator=";")


# ----------------------------------------------------------------------------- properties

int32 = st.integers(min_value=-(2**31), max_value=2**31 - 1)
replies = st.one_of(
    st.sampled_from([StatusReply("RECIEVE_OK"), StatusReply("FULL_BUFFER")]),
    st.builds(SpeedReading, left=int32, right=int32),
    st.builds(PositionReading, left=int32, right=int32),
    st.builds(LogReport, st.integers(0, 4), st.integers(1, 4)),
)


def _encode_reply(reply: object, separator: str) -> bytes:
    if isinstance(reply, StatusReply):
        return wire.encode_status(reply.status)
    if isinstance(reply, SpeedReading):
        return wire.encode_wheel_speeds(left=reply.left, right=reply.right, separator=separator)
    if isinstance(reply, PositionReading):
        return wire.encode_wheel_positions(left=reply.left, right=reply.right, separator=separator)
    assert isinstance(reply, LogReport)
    return wire.encode_log_report(reply.state, reply.direction)


@settings(max_examples=300)
@given(
    st.lists(st.tuples(replies, st.sampled_from([" ", ","])), max_size=20),
    st.lists(st.integers(min_value=0, max_value=2000), max_size=30),
)
def test_any_split_of_a_valid_stream_decodes_to_the_same_replies(items: list, cuts: list[int]) -> None:
    stream = b"".join(_encode_reply(reply, sep) for reply, sep in items)
    points = sorted({min(cut, len(stream)) for cut in cuts} | {0, len(stream)})
    decoder = ReplyDecoder()
    out = []
    for start, end in itertools.pairwise(points):
        out.extend(decoder.feed(stream[start:end]))
    assert out == [reply for reply, _ in items]
    assert decoder.pending == 0 and decoder.malformed == 0


@settings(max_examples=300)
@given(st.lists(st.binary(max_size=200), max_size=20))
def test_random_bytes_never_raise_and_the_buffer_stays_bounded(chunks: list[bytes]) -> None:
    decoder = ReplyDecoder(max_frame=128)
    requests = RequestDecoder(max_frame=128)
    for chunk in chunks:
        for item in decoder.feed(chunk):
            assert isinstance(item, (StatusReply, SpeedReading, PositionReading, LogReport, Malformed))
        requests.feed(chunk)
        assert decoder.pending <= 128 + len(chunk)
    # after any garbage, a valid reply still comes through
    assert decoder.feed(b'{"status":"RECIEVE_OK"}')[-1] == StatusReply("RECIEVE_OK")


@settings(max_examples=200)
@given(st.binary(max_size=40).filter(lambda b: b"{" not in b), replies)
def test_garbage_before_a_reply_is_skipped_and_counted(garbage: bytes, reply: object) -> None:
    decoder = ReplyDecoder()
    out = decoder.feed(garbage + _encode_reply(reply, " "))
    assert out[-1] == reply
    assert decoder.garbage_bytes == (len(garbage) if garbage.strip() else 0)


@given(st.floats(min_value=-1.0, max_value=1.0), st.floats(min_value=-1.0, max_value=1.0))
def test_any_legal_velocity_round_trips_to_six_decimals(right: float, left: float) -> None:
    (decoded,) = RequestDecoder().feed(encode_request(wire.set_velocity(left=left, right=right)))
    assert isinstance(decoded, Request)
    assert decoded.right == pytest.approx(right, abs=5e-7)
    assert decoded.left == pytest.approx(left, abs=5e-7)


# ---- the reply fast paths read what the field-by-field parser reads

_reply_text = st.one_of(
    st.builds(
        lambda left, right, s1, s2, sep, c, pad, tail: (
            f'{{{pad}"LeftWheelSpeed"{s1}{left}{c}{sep}"RightWheelSpeed"{s2}{right}{tail}}}'
        ).encode(),
        st.integers(-(10**10), 10**10),
        st.integers(-(10**10), 10**10),
        st.sampled_from([":", "=", " : ", "= "]),
        st.sampled_from([":", "=", " :", "=  "]),
        st.sampled_from(["", " ", "  ", "\t"]),
        st.sampled_from(["", ","]),
        st.sampled_from(["", " ", "\n"]),
        st.sampled_from(["", " ", ",", " ,", ", ", ",,", " , "]),
    ),
    st.sampled_from([b'{"status":"OK"}', b'{"status":"FULL_BUFFER"}', b'{"status":""}', b'{"status":OK}', b'{"status":7}']),
    st.binary(max_size=60).map(lambda b: b"{" + b.replace(b"{", b"").replace(b"}", b"") + b"}"),
)


@given(_reply_text)
@example(b'{"LeftWheelSpeed":1' + b" " * 490 + b"}")  # a hostile frame the regex once took 500 us to give up on
@example(b'{"LeftWheelSpeed":1' + b" " * 60 + b"," + b" " * 60 + b"}")
@example(b'{"status":"RECIEVE_OK"}')
def test_the_reply_fast_paths_read_what_the_field_parser_reads(frame: bytes) -> None:
    from blackmetal.wire import _parse_reply, parse_reply

    assert repr(parse_reply(frame)) == repr(_parse_reply(frame))
    assert repr(parse_reply(frame)) == repr(_parse_reply(frame))  # a second time: from the status cache


@pytest.mark.parametrize("code", list(CommandCode))
def test_a_known_request_frame_reads_as_the_parser_reads_it(code: CommandCode) -> None:
    from blackmetal.wire import _parse_request, parse_request

    request = wire.set_velocity(left=0.1, right=-0.2) if code is CommandCode.SET_LR_WHEEL_VELOCITY else wire.simple(code)
    if code is CommandCode.SET_LR_WHEEL_POSITION:
        request = Request(CommandCode.SET_LR_WHEEL_POSITION, left=5, right=-7)
    frame = encode_request(request)
    assert parse_request(frame) == _parse_request(frame) == request
    assert parse_request(frame[:-1] + b" }") == _parse_request(frame[:-1] + b" }") == request  # not the known bytes: parsed
