"""The front before foxglove-sdk, sans I/O: the handshake rewrite, frames, the tap that finds message ends, the messages it sends."""

from __future__ import annotations

import itertools
import json
import random

import pytest

from blackmetal.foxglove import front
from blackmetal.foxglove.front import (
    LEGACY_SUBPROTOCOL,
    OP_BINARY,
    OP_CLOSE,
    OP_CONTINUATION,
    OP_TEXT,
    SDK_SUBPROTOCOL,
    FrameTap,
    offered_subprotocols,
    rewrite_request,
    rewrite_response,
    switches_protocols,
    ws_frame,
)
from blackmetal.foxglove.naming import StatusLevel


def request(*protocol_headers: str) -> bytes:
    lines = [
        "GET / HTTP/1.1",
        "Host: 127.0.0.1:8765",
        "Upgrade: websocket",
        "Connection: Upgrade",
        "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==",
    ]
    lines += [f"Sec-WebSocket-Protocol: {value}" for value in protocol_headers]
    return ("\r\n".join([*lines, "Sec-WebSocket-Version: 13", "", ""])).encode()


def test_a_client_offering_only_the_older_subprotocol_is_offered_to_the_sdk_under_its_name() -> None:
    head, shown = rewrite_request(request("foxglove.websocket.v1"))
    assert offered_subprotocols(head) == [SDK_SUBPROTOCOL] and shown == LEGACY_SUBPROTOCOL
    assert head.endswith(b"\r\n\r\n") and b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==" in head
    answer = b"HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nsec-websocket-protocol: foxglove.sdk.v1\r\n\r\n"
    assert switches_protocols(answer)
    assert b"Sec-WebSocket-Protocol: foxglove.websocket.v1\r\n" in rewrite_response(answer, LEGACY_SUBPROTOCOL)


@pytest.mark.parametrize(
    "headers",
    [
        ("foxglove.sdk.v1, foxglove.websocket.v1",),  # current Foxglove
        ("foxglove.websocket.v1, foxglove.sdk.v1",),  # Lichtblick >= 1.22.1
        ("foxglove.websocket.v1", "foxglove.sdk.v1"),  # two headers
        ("other.v1",),  # for the SDK to refuse
        (),
    ],
)
def test_requests_the_sdk_can_answer_itself_pass_unchanged(headers: tuple[str, ...]) -> None:
    assert rewrite_request(request(*headers)) == (request(*headers), None)
    assert not switches_protocols(b"HTTP/1.1 400 Bad Request\r\n\r\n")


def test_the_tap_finds_every_message_end_and_text_however_the_bytes_are_cut() -> None:
    rng = random.Random(7)
    status = json.dumps({"op": "status", "level": 2, "message": "x" * 300}).encode()
    frames = [
        (ws_frame(OP_TEXT, status), True),
        (ws_frame(OP_BINARY, bytes(70_000)), True),  # 64-bit length
        (ws_frame(OP_BINARY, bytes(200)), True),  # 16-bit length
        (bytes([OP_TEXT]) + bytes([5]) + b'{"op"', False),  # a fragmented text message ...
        (ws_frame(0x9, b"ping"), False),  # ... a ping between its frames is no boundary ...
        (bytes([0x80 | OP_CONTINUATION]) + bytes([7]) + b':"x"}  ', True),  # ... its last frame is
        (ws_frame(OP_TEXT, b""), True),
        (ws_frame(OP_TEXT, b'{"a": 1}', mask=b"\x01\x02\x03\x04"), True),  # a client's frame, masked
        (ws_frame(OP_CLOSE, b"\x03\xe8"), True),
    ]
    stream = b"".join(frame for frame, _ in frames)
    ends = list(itertools.accumulate(len(frame) for frame, _ in frames))
    expected = [end for end, (_, boundary) in zip(ends, frames, strict=True) if boundary]
    for _ in range(50):
        texts: list[bytes] = []
        tap = FrameTap(texts.append)
        cuts = sorted(rng.sample(range(1, len(stream)), rng.randint(0, 40)))
        found: list[int] = []
        for start, end in itertools.pairwise([0, *cuts, len(stream)]):
            found += [start + offset for offset in tap.feed(stream[start:end])]
            assert tap.at_boundary == (end in expected or end == 0)
        assert found == expected
        assert texts == [status, b'{"op":"x"}  ', b"", b'{"a": 1}']
        assert tap.closed


def test_a_frame_carries_its_length_in_the_three_sizes_and_a_client_frame_is_masked() -> None:
    for size, head in ((5, 2), (300, 4), (70_000, 10)):
        frame = ws_frame(OP_BINARY, b"x" * size)
        assert len(frame) == head + size and frame[0] == 0x80 | OP_BINARY and not frame[1] & 0x80
    masked = ws_frame(OP_TEXT, b"hello", mask=b"\x01\x02\x03\x04")
    assert masked[1] == 0x80 | 5 and masked[2:6] == b"\x01\x02\x03\x04"
    assert bytes(b ^ masked[2 + i % 4] for i, b in enumerate(masked[6:])) == b"hello"
    texts: list[bytes] = []
    assert FrameTap(texts.append).feed(masked) == [len(masked)] and texts == [b"hello"], "the tap unmasks"


def test_a_text_longer_than_the_limit_is_not_read_but_its_end_is_found() -> None:
    texts: list[bytes] = []
    tap = FrameTap(texts.append, text_limit=4)
    frame = ws_frame(OP_TEXT, b"too long")
    assert tap.feed(frame) == [len(frame)] and texts == [] and tap.at_boundary


def test_the_messages_the_front_sends_and_reads() -> None:
    assert (
        front.url("0.0.0.0", 8765) == "ws://127.0.0.1:8765"
        and front.url("::", 1) == "ws://127.0.0.1:1"
        and front.url("10.0.0.2", 9) == "ws://10.0.0.2:9"
    )
    advertise = json.loads(front.marker_advertisement("abc"))
    assert advertise["op"] == "advertise"
    assert advertise["channels"] == [{"id": front.MARKER_CHANNEL_ID, "topic": front.MARKER_TOPIC, "encoding": "json", "schemaName": "abc"}]
    assert json.loads(front.status_message(StatusLevel.ERROR, "no")) == {"op": "status", "level": 2, "message": "no"}
    failure = front.server_op.decode(b'{"op": "serviceCallFailure", "serviceId": 3, "callId": 7, "message": "x", "extra": 1}')
    assert (failure.op, failure.service_id, failure.call_id, failure.message) == ("serviceCallFailure", 3, 7, "x")
    assert front.server_op.decode(b'{"op": "status", "level": 1, "message": "m"}').level == 1


@pytest.mark.parametrize(
    "status, upgraded", [(b"HTTP/1.1 101 Switching Protocols", True), (b"HTTP/1.1 400 Bad Request", False), (b"", False)]
)
def test_only_a_101_switches_protocols(status: bytes, upgraded: bool) -> None:
    assert switches_protocols(status + b"\r\n\r\n") is upgraded


def test_the_servers_first_message_gets_a_ros_profile_so_the_3d_panel_may_publish_and_anything_else_passes_as_it_came() -> None:
    import asyncio

    info = {"op": "serverInfo", "name": "blackmetal", "capabilities": ["clientPublish"], "supportedEncodings": ["json"]}
    assert json.loads(front.with_profile(json.dumps(info).encode()) or b"")["metadata"] == {"ROS_DISTRO": "humble"}
    ours = json.loads(front.with_profile(json.dumps({**info, "metadata": {"ROS_DISTRO": "jazzy", "a": "b"}}).encode()) or b"")
    assert ours["metadata"] == {"ROS_DISTRO": "jazzy", "a": "b"}, "what the server says wins"
    assert front.with_profile(b'{"op": "advertise", "channels": []}') is None and front.with_profile(b"\xff not json") is None

    async def first(*frames: bytes) -> tuple[bytes, bytes]:
        reader = asyncio.StreamReader()
        for frame in frames:
            reader.feed_data(frame)
        reader.feed_eof()
        return await front.first_message(reader), await reader.read()

    long_info = {**info, "name": "x" * 70_000}  # a 64-bit length
    for sent in (info, long_info):
        message, rest = asyncio.run(first(ws_frame(OP_TEXT, json.dumps(sent).encode()), ws_frame(OP_BINARY, b"next")))
        tap_seen: list[bytes] = []
        FrameTap(tap_seen.append, text_limit=1 << 20).feed(message)
        assert json.loads(tap_seen[0]) == {**sent, "metadata": front.PROFILE_METADATA} and rest == ws_frame(OP_BINARY, b"next")
    binary = ws_frame(OP_BINARY, b"\x01" * 200)
    assert asyncio.run(first(binary)) == (binary, b""), "not a serverInfo: unchanged"
    with pytest.raises(asyncio.IncompleteReadError):
        asyncio.run(first(ws_frame(OP_TEXT, b"{}")[:3]))
