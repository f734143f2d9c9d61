"""The front of the view's WebSocket server: a thin proxy before foxglove-sdk, its handshake and frames sans I/O.

It renames the older clients' subprotocol in the handshake, then copies bytes both ways unchanged; following the
server's frames it sends one client a status and sees the SDK's own refusals; a marker channel named by a random
token tells which SDK client a connection is (docs/foxglove.md, "Foxglove and Lichtblick").
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import Callable
from dataclasses import InitVar, dataclass, field

import msgspec

from .naming import CLIENT_ENCODING, StatusLevel

#: The subprotocol foxglove-sdk speaks, and the older name of the same protocol.
SDK_SUBPROTOCOL = "foxglove.sdk.v1"
LEGACY_SUBPROTOCOL = "foxglove.websocket.v1"
SUBPROTOCOLS = (SDK_SUBPROTOCOL, LEGACY_SUBPROTOCOL)
#: The SDK server listens here, on a free port; clients reach it through the front.
INNER_HOST = "127.0.0.1"
#: The marker channel the front advertises on each connection (ids are the client's to choose; this one is the last).
MARKER_CHANNEL_ID = 0xFFFFFFFF
MARKER_TOPIC = "/.blackmetal/connection"
HEAD_LIMIT = 64 * 1024
READ_SIZE = 64 * 1024
HANDSHAKE_TIMEOUT_S = 10.0
#: A server text message longer than this is not read for refusals (statuses are short; advertisements can be long).
TEXT_LIMIT = 64 * 1024
#: Added to the server's serverInfo metadata: Studio and Lichtblick let the 3D panel's publish tools (a goal, a pose
#: estimate) send only to a server with a ROS profile, which they read from ``ROS_DISTRO``; what clients publish is
#: JSON either way (docs/foxglove.md, "Sending goals").
PROFILE_METADATA = {"ROS_DISTRO": "humble"}


OP_CONTINUATION, OP_TEXT, OP_BINARY, OP_CLOSE = 0x0, 0x1, 0x2, 0x8


def url(host: str, port: int) -> str:
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    return f"ws://{shown}:{port}"


def _header_lines(head: bytes) -> list[str]:
    return head.decode("latin-1").split("\r\n")


def _names_protocol(line: str) -> bool:
    return line.partition(":")[0].strip().lower() == "sec-websocket-protocol"


def offered_subprotocols(head: bytes) -> list[str]:
    values = [line.partition(":")[2] for line in _header_lines(head)[1:] if _names_protocol(line)]
    return [item.strip() for value in values for item in value.split(",") if item.strip()]


def rewrite_request(head: bytes) -> tuple[bytes, str | None]:
    """The request for the SDK, and the subprotocol to name in the answer when it was renamed (only a client offering
    ``foxglove.websocket.v1`` without ``foxglove.sdk.v1`` is)."""
    offered = offered_subprotocols(head)
    if SDK_SUBPROTOCOL in offered or LEGACY_SUBPROTOCOL not in offered:
        return head, None
    lines = [line for line in _header_lines(head) if not _names_protocol(line)]
    # the head ends with "\r\n\r\n": the last two lines are empty
    lines.insert(len(lines) - 2, f"Sec-WebSocket-Protocol: {SDK_SUBPROTOCOL}")
    return "\r\n".join(lines).encode("latin-1"), LEGACY_SUBPROTOCOL


def switches_protocols(response_head: bytes) -> bool:
    status = _header_lines(response_head)[0].split()
    return len(status) >= 2 and status[1] == "101"


def rewrite_response(head: bytes, subprotocol: str) -> bytes:
    lines = [f"Sec-WebSocket-Protocol: {subprotocol}" if _names_protocol(line) else line for line in _header_lines(head)]
    return "\r\n".join(lines).encode("latin-1")


def ws_frame(opcode: int, payload: bytes, mask: bytes | None = None) -> bytes:
    """One final WebSocket frame; ``mask`` (4 bytes) for frames a client sends."""
    head = bytearray([0x80 | opcode])
    masked = 0x80 if mask else 0
    size = len(payload)
    if size < 126:
        head.append(masked | size)
    else:
        wide = size >= 1 << 16
        head.append(masked | (127 if wide else 126))
        head += size.to_bytes(8 if wide else 2, "big")
    if mask:
        head += mask
        payload = bytes(byte ^ mask[i % 4] for i, byte in enumerate(payload))
    return bytes(head) + payload


def with_profile(message: bytes) -> bytes | None:
    """A serverInfo message with :data:`PROFILE_METADATA` added (what the server set itself wins); None for another message."""
    try:
        op = json.loads(message)
    except (ValueError, UnicodeDecodeError):
        return None
    if not isinstance(op, dict) or op.get("op") != "serverInfo":
        return None
    metadata = op.get("metadata")
    op["metadata"] = {**PROFILE_METADATA, **(metadata if isinstance(metadata, dict) else {})}
    return json.dumps(op).encode()


async def first_message(reader: asyncio.StreamReader) -> bytes:
    """The server's first frame (its serverInfo) read whole, with the profile added when it is one; as it came otherwise."""
    head = await reader.readexactly(2)
    head += await reader.readexactly(_header_size(head) - 2)
    length = head[1] & 0x7F
    if length >= 126:
        length = int.from_bytes(head[2 : 4 if length == 126 else 10], "big")
    payload = await reader.readexactly(length)
    plain_text = head[0] == 0x80 | OP_TEXT and not head[1] & 0x80  # final, uncompressed, unmasked text
    added = with_profile(payload) if plain_text else None
    return ws_frame(OP_TEXT, added) if added is not None else head + payload


def _header_size(head: bytes | bytearray) -> int:
    if len(head) < 2:
        return 2
    length = head[1] & 0x7F
    extended = 2 if length == 126 else 8 if length == 127 else 0
    return 2 + extended + (4 if head[1] & 0x80 else 0)


@dataclass(eq=False)
class FrameTap:
    """Follows the frames of one direction of a WebSocket without changing a byte: where messages end, and the text ones.

    :meth:`feed` takes the bytes in any cut and returns the offsets where a whole message ends (a frame can go there);
    whole text messages (up to ``text_limit`` bytes) go to ``on_text``.
    """

    on_text: Callable[[bytes], None] | None = None
    text_limit: int = TEXT_LIMIT
    closed: bool = False
    _head: bytearray = field(default_factory=bytearray, init=False)
    _left: int = field(default=0, init=False)
    _in_frame: bool = field(default=False, init=False)
    _opcode: int = field(default=0, init=False)
    _fin: bool = field(default=True, init=False)
    _mask: bytes = field(default=b"", init=False)
    _offset: int = field(default=0, init=False)
    _fragmented: bool = field(default=False, init=False)
    _text: bytearray | None = field(default=None, init=False)

    @property
    def at_boundary(self) -> bool:
        return not self._in_frame and not self._head and not self._fragmented

    def feed(self, data: bytes) -> list[int]:
        boundaries: list[int] = []
        i, size = 0, len(data)
        while i < size or (self._in_frame and self._left == 0):
            if not self._in_frame:
                need = _header_size(self._head)
                while len(self._head) < need and i < size:
                    take = min(need - len(self._head), size - i)
                    self._head += data[i : i + take]
                    i += take
                    need = _header_size(self._head)
                if len(self._head) < need:
                    break
                self._start_frame()
                continue
            take = min(self._left, size - i)
            if self._text is not None and self._opcode in (OP_TEXT, OP_CONTINUATION) and take:
                self._collect(data[i : i + take])
            i += take
            self._left -= take
            if self._left == 0 and self._end_frame():
                boundaries.append(i)
        return boundaries

    def _start_frame(self) -> None:
        head = bytes(self._head)
        self._head.clear()
        self._fin = bool(head[0] & 0x80)
        compressed = bool(head[0] & 0x40)
        self._opcode = head[0] & 0x0F
        length = head[1] & 0x7F
        at = {126: 4, 127: 10}.get(length, 2)
        if at > 2:
            length = int.from_bytes(head[2:at], "big")
        self._mask = head[at : at + 4] if head[1] & 0x80 else b""
        self._offset = 0
        self._left = length
        self._in_frame = True
        if self._opcode == OP_TEXT:
            self._text = None if compressed else bytearray()
        elif self._opcode == OP_BINARY:
            self._text = None

    def _collect(self, chunk: bytes) -> None:
        assert self._text is not None
        if self._mask:
            chunk = bytes(byte ^ self._mask[(self._offset + k) % 4] for k, byte in enumerate(chunk))
        self._offset += len(chunk)
        if len(self._text) + len(chunk) > self.text_limit:
            self._text = None
        else:
            self._text += chunk

    def _end_frame(self) -> bool:
        """The current frame is complete; True when a whole message ended with it."""
        self._in_frame = False
        if self._opcode >= OP_CLOSE:  # a control frame: may come between the frames of a fragmented message
            if self._opcode == OP_CLOSE:
                self.closed = True
            return not self._fragmented
        if not self._fin:
            self._fragmented = True
            return False
        self._fragmented = False
        text, self._text = self._text, None
        if text is not None and self.on_text is not None:
            self.on_text(bytes(text))
        return True


class _ServerOp(msgspec.Struct):
    op: str
    level: int = 0
    message: str = ""
    service_id: int | None = msgspec.field(default=None, name="serviceId")
    call_id: int | None = msgspec.field(default=None, name="callId")


server_op = msgspec.json.Decoder(_ServerOp)


def marker_advertisement(token: str) -> bytes:
    channel = {"id": MARKER_CHANNEL_ID, "topic": MARKER_TOPIC, "encoding": CLIENT_ENCODING, "schemaName": token}
    return json.dumps({"op": "advertise", "channels": [channel]}).encode()


def status_message(level: StatusLevel, message: str) -> bytes:
    return json.dumps({"op": "status", "level": int(level), "message": message}).encode()


@dataclass(eq=False)
class Connection:
    """One client connection through the front: its writer, the tap on what the server sends it, statuses waiting for a message boundary."""

    token: str
    writer: asyncio.StreamWriter
    upstream: asyncio.StreamWriter
    on_text: InitVar[Callable[[Connection, bytes], None]]
    client: int | None = None
    outbox: list[bytes] = field(default_factory=list)
    busy: bool = False

    def __post_init__(self, on_text: Callable[[Connection, bytes], None]) -> None:
        self.tap = FrameTap(lambda text: on_text(self, text))

    def send(self, frame: bytes) -> None:
        """At the next message boundary of the server's stream."""
        if self.tap.closed or self.writer.is_closing():
            return
        self.outbox.append(frame)
        if not self.busy and self.tap.at_boundary:
            self.flush()

    def flush(self) -> None:
        for frame in self.outbox:
            self.writer.write(frame)
        self.outbox.clear()

    def close(self) -> None:
        for writer in (self.writer, self.upstream):
            with contextlib.suppress(Exception):
                writer.close()
