"""The Foxglove view's host: the WebSocket server the app connects to and, with ``--mcap``, the MCAP file.

The view (:mod:`blackmetal.foxglove.core`) logs into channels of the
current Foxglove context; this host opens what those channels reach (the
foxglove-sdk server, then the file) and closes them in reverse order. It
feeds :class:`~blackmetal.foxglove.core.Controls` with what clients publish
and call, stamped with the clock, and runs its deadlines on the shared
:class:`~blackmetal.runtime.driver.CoreTimer`.

**The front.** foxglove-sdk accepts only the WebSocket subprotocol
``foxglove.sdk.v1`` and answers HTTP 400 to a client that offers only the
older ``foxglove.websocket.v1`` (Lichtblick before 1.22.1, foxglove_bridge
0.8-era clients, roslibjs-foxglove), and no option of the SDK changes that.
The two names stand for the same protocol, so the SDK server listens on a
free loopback port and a thin front listens where clients connect: it reads
the HTTP upgrade request, offers ``foxglove.sdk.v1`` to the SDK in place of
``foxglove.websocket.v1`` when that is all the client offers, writes the
client's own name back into the 101 answer, and from then on copies bytes
both ways unchanged. Following the server's frames (never changing them) it
also lets the view (a) send a status message to one client, which the
SDK's Python API cannot (its ``publish_status`` goes to every client), and
(b) see the refusals the SDK sends by itself (bad JSON, an unknown channel
or service) so they are reported too. To know which SDK client a
connection is, the front advertises, first thing on each connection, a
marker channel whose schema name is the connection's random token.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import itertools
import json
import os
import secrets
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Protocol

import msgspec

from blackmetal.runtime.driver import CoreTimer
from blackmetal.runtime.intake import Intake
from blackmetal.schemas import BlackmetalError, ConfigError, GatewayParams, Param

from .core import CLIENT_ENCODING, SERVICE_SPECS, ServerRefusal, Service, StatusLevel
from .params import Parameters
from .settings import FoxgloveSettings
from .watch import Watch

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
#: A service handler thread waits this much longer than the call's time limit before it gives up on its own.
CALL_MARGIN_S = 1.0

OP_CONTINUATION, OP_TEXT, OP_BINARY, OP_CLOSE = 0x0, 0x1, 0x2, 0x8


def url(host: str, port: int) -> str:
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    return f"ws://{shown}:{port}"


# --------------------------------------------------------------------------- the handshake, sans I/O
def _header_lines(head: bytes) -> list[str]:
    return head.decode("latin-1").split("\r\n")


def offered_subprotocols(head: bytes) -> list[str]:
    """The subprotocols an HTTP upgrade request offers, in its order (every Sec-WebSocket-Protocol header, comma lists split)."""
    offered: list[str] = []
    for line in _header_lines(head)[1:]:
        name, _, value = line.partition(":")
        if name.strip().lower() == "sec-websocket-protocol":
            offered += [item.strip() for item in value.split(",") if item.strip()]
    return offered


def rewrite_request(head: bytes) -> tuple[bytes, str | None]:
    """The request for the SDK, and the subprotocol to name in the answer when it had to be renamed (None: unchanged).

    A client that offers ``foxglove.sdk.v1`` is passed on as it is; one that
    offers ``foxglove.websocket.v1`` without it is offered to the SDK as
    ``foxglove.sdk.v1``; any other is passed on for the SDK to refuse.
    """
    offered = offered_subprotocols(head)
    if SDK_SUBPROTOCOL in offered or LEGACY_SUBPROTOCOL not in offered:
        return head, None
    lines = [line for line in _header_lines(head) if line.partition(":")[0].strip().lower() != "sec-websocket-protocol"]
    # the head ends with "\r\n\r\n": the last two lines are empty
    lines.insert(len(lines) - 2, f"Sec-WebSocket-Protocol: {SDK_SUBPROTOCOL}")
    return "\r\n".join(lines).encode("latin-1"), LEGACY_SUBPROTOCOL


def switches_protocols(response_head: bytes) -> bool:
    """The server's answer accepts the upgrade (HTTP 101)."""
    status = _header_lines(response_head)[0].split()
    return len(status) >= 2 and status[1] == "101"


def rewrite_response(head: bytes, subprotocol: str) -> bytes:
    """The server's 101 answer with ``subprotocol`` as the chosen subprotocol (the one the client offered)."""
    lines = _header_lines(head)
    for index, line in enumerate(lines):
        if line.partition(":")[0].strip().lower() == "sec-websocket-protocol":
            lines[index] = f"Sec-WebSocket-Protocol: {subprotocol}"
    return "\r\n".join(lines).encode("latin-1")


# --------------------------------------------------------------------------- frames, sans I/O
def ws_frame(opcode: int, payload: bytes, mask: bytes | None = None) -> bytes:
    """One final WebSocket frame; ``mask`` (4 bytes) for frames a client sends."""
    head = bytearray([0x80 | opcode])
    masked = 0x80 if mask else 0
    size = len(payload)
    if size < 126:
        head.append(masked | size)
    elif size < 1 << 16:
        head.append(masked | 126)
        head += size.to_bytes(2, "big")
    else:
        head.append(masked | 127)
        head += size.to_bytes(8, "big")
    if mask:
        head += mask
        payload = bytes(byte ^ mask[i % 4] for i, byte in enumerate(payload))
    return bytes(head) + payload


def _header_size(head: bytes | bytearray) -> int:
    """Bytes in a frame header, as far as its first two bytes tell (2 until they are there)."""
    if len(head) < 2:
        return 2
    length = head[1] & 0x7F
    extended = 2 if length == 126 else 8 if length == 127 else 0
    return 2 + extended + (4 if head[1] & 0x80 else 0)


class FrameTap:
    """Follows the frames of one direction of a WebSocket without changing a byte: where messages end, and the text ones.

    :meth:`feed` takes the bytes as they come (any cut) and returns the
    offsets in them at which a whole message ends: a frame can be inserted
    there. Complete text messages (up to ``text_limit`` bytes) go to
    ``on_text``.
    """

    def __init__(self, on_text: Callable[[bytes], None] | None = None, text_limit: int = TEXT_LIMIT) -> None:
        self.on_text = on_text
        self.text_limit = text_limit
        self.closed = False
        self._head = bytearray()
        self._left = 0
        self._in_frame = False
        self._opcode = 0
        self._fin = True
        self._mask = b""
        self._offset = 0
        self._fragmented = False
        self._text: bytearray | None = None

    @property
    def at_boundary(self) -> bool:
        """No frame and no fragmented message is half through."""
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
        at = 2
        if length == 126:
            length, at = int.from_bytes(head[2:4], "big"), 4
        elif length == 127:
            length, at = int.from_bytes(head[2:10], "big"), 10
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
    """The fields of a server's JSON message that tell a refusal."""

    op: str
    level: int = 0
    message: str = ""
    service_id: int | None = msgspec.field(default=None, name="serviceId")
    call_id: int | None = msgspec.field(default=None, name="callId")


_server_op = msgspec.json.Decoder(_ServerOp)


def marker_advertisement(token: str) -> bytes:
    channel = {"id": MARKER_CHANNEL_ID, "topic": MARKER_TOPIC, "encoding": CLIENT_ENCODING, "schemaName": token}
    return json.dumps({"op": "advertise", "channels": [channel]}).encode()


def status_message(level: StatusLevel, message: str) -> bytes:
    return json.dumps({"op": "status", "level": int(level), "message": message}).encode()


# --------------------------------------------------------------------------- what the SDK's threads hand over
class EventKind(Enum):
    ADVERTISE = "advertise"
    UNADVERTISE = "unadvertise"
    MESSAGE = "message"
    SUBSCRIBE = "subscribe"
    UNSUBSCRIBE = "unsubscribe"


@dataclass(frozen=True, slots=True)
class ClientEvent:
    """A client advertised, unadvertised or published (from the SDK's listener, on its thread)."""

    kind: EventKind
    client: int
    channel: int
    topic: str = ""
    encoding: str = ""
    schema_name: str = ""
    data: bytes = b""


@dataclass(frozen=True, slots=True)
class ServiceCallIn:
    """A service call from the SDK's handler thread, which waits on ``future``."""

    service: str
    client: int
    call_id: int
    payload: bytes
    future: concurrent.futures.Future[bytes] = field(compare=False)


class ServiceFailure(BlackmetalError):
    """Raised in a service handler: the SDK answers the call with a service call failure carrying this text."""


@dataclass(frozen=True, slots=True)
class ParamsSetIn:
    """A client's setParameters from the SDK's thread, which waits on ``future`` for the values to answer with."""

    client: int
    values: list[tuple[str, object]]
    future: concurrent.futures.Future[list[Param]] = field(compare=False)


def _listener(
    put: Callable[[ClientEvent], None],
    put_subscription: Callable[[ClientEvent], None],
    get_params: Callable[[list[str]], list[Any]],
    set_params: Callable[[int, list[Any]], list[Any]],
) -> Any:
    """A ServerListener that hands every client event over to the view's loop (parameters: answered from the loop's snapshot, or waited for)."""
    from foxglove.websocket import ServerListener

    class Listener(ServerListener):
        def on_subscribe(self, client: Any, channel: Any) -> None:
            put_subscription(ClientEvent(EventKind.SUBSCRIBE, client.id, channel.id, channel.topic))

        def on_unsubscribe(self, client: Any, channel: Any) -> None:
            put_subscription(ClientEvent(EventKind.UNSUBSCRIBE, client.id, channel.id, channel.topic))

        def on_get_parameters(self, client: Any, param_names: list[str], request_id: str | None = None) -> list[Any]:
            return get_params(param_names)

        def on_set_parameters(self, client: Any, parameters: list[Any], request_id: str | None = None) -> list[Any]:
            return set_params(client.id, parameters)

        def on_client_advertise(self, client: Any, channel: Any) -> None:
            put(ClientEvent(EventKind.ADVERTISE, client.id, channel.id, channel.topic, channel.encoding, channel.schema_name))

        def on_client_unadvertise(self, client: Any, client_channel_id: int) -> None:
            put(ClientEvent(EventKind.UNADVERTISE, client.id, client_channel_id))

        def on_message_data(self, client: Any, client_channel_id: int, data: bytes) -> None:
            put(ClientEvent(EventKind.MESSAGE, client.id, client_channel_id, data=bytes(data)))

    return Listener()


def foxglove_parameter(param: Param) -> Any:
    """A gateway parameter as the SDK sends it (a double keeps its type even when whole: 0.5 and 1.0 alike)."""
    from foxglove import Parameter, ParameterType

    if param.type == "double" and isinstance(param.value, (int, float)) and not isinstance(param.value, bool):
        return Parameter(param.name, value=float(param.value), type=ParameterType.Float64)
    return Parameter(param.name, value=param.value)


class Viewer(Protocol):
    """What the host tells the view about its clients' subscriptions."""

    def subscribed(self, topic: str) -> None:
        """A client subscribed to ``topic`` (what is sent once, the URDF, goes to it now)."""

    def watch_changed(self) -> None:
        """The watched topics changed: subscribe to the keys they need, and only those."""


class ClientCore(Protocol):
    """What the host feeds with the clients' doings: :class:`Controls` for one robot, ``FleetControls`` for a fleet."""

    def on_advertise(self, client: int, channel: int, topic: str, encoding: str, schema_name: str, now: float) -> None: ...
    def on_unadvertise(self, client: int, channel: int, now: float) -> None: ...
    def on_client_gone(self, client: int, now: float) -> None: ...
    def on_message(self, client: int, channel: int, data: bytes, now: float) -> None: ...
    def on_service_call(self, call: int, client: int, service: str, payload: bytes, now: float) -> None: ...
    def on_server_refusal(self, client: int | None, kind: ServerRefusal, message: str, now: float) -> None: ...
    def tick(self, now: float) -> None: ...
    def next_deadline(self) -> float: ...


class _Connection:
    """One client connection through the front: its writer, the tap on what the server sends it, statuses waiting for a message boundary."""

    def __init__(
        self, token: str, writer: asyncio.StreamWriter, upstream: asyncio.StreamWriter, on_text: Callable[[_Connection, bytes], None]
    ) -> None:
        self.token = token
        self.writer = writer
        self.upstream = upstream
        self.tap = FrameTap(lambda text: on_text(self, text))
        self.client: int | None = None
        self.outbox: list[bytes] = []
        self.busy = False

    def send(self, frame: bytes) -> None:
        """Send ``frame`` to the client at the next message boundary of the server's stream."""
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
            try:
                writer.close()
            except Exception:
                pass


class Timed(Protocol):
    """A part with timers of its own: the host runs ``tick`` at ``next_deadline``."""

    def tick(self, now: float) -> None: ...
    def next_deadline(self) -> float: ...


class _Together:
    """Several timed parts as one for the host's one timer."""

    def __init__(self, parts: list[Timed]) -> None:
        self.parts = parts

    def tick(self, now: float) -> None:
        for part in self.parts:
            part.tick(now)

    def next_deadline(self) -> float:
        return min(part.next_deadline() for part in self.parts)


class ParamsRobots(Protocol):
    """What :class:`Parameters` asks of a robot's gateway, through its Zenoh edge."""

    def ask_params(self, robot_id: str) -> None: ...
    def set_params(self, robot_id: str, call: int, payload: bytes) -> None: ...
    def report(self, robot_id: str | None, topic: str, reason: str, text: str, now: float) -> None: ...


@dataclass(slots=True)
class _Call:
    client: int
    call_id: int
    future: concurrent.futures.Future[bytes]


def start_server(settings: FoxgloveSettings, listener: Any = None, services: list[Any] | None = None) -> Any:
    """The foxglove-sdk server on a free loopback port, with client publish, services (JSON) and parameters."""
    import foxglove
    from foxglove.websocket import Capability

    try:
        return foxglove.start_server(
            name="blackmetal",
            host=INNER_HOST,
            port=0,
            capabilities=[Capability.ClientPublish, Capability.Services, Capability.Parameters],
            server_listener=listener,
            supported_encodings=[CLIENT_ENCODING],
            services=services,
        )
    except Exception as exc:  # the SDK raises its own error with the OS reason
        raise ConfigError(f"cannot start the Foxglove server on {INNER_HOST} ({exc})") from None


class FoxgloveHost:
    """The front, the SDK server (and the MCAP file) of one view; feeds :class:`Controls`; :meth:`close` stops them, the file first."""

    def __init__(
        self, settings: FoxgloveSettings, clock: Callable[[], float] = time.monotonic, services: dict[str, Service] | None = None
    ) -> None:
        """``services``: the name each service is advertised under (default: ``set_estop``, ``reset_odometry``; a fleet's ``/r3/set_estop``, ...)."""
        import foxglove

        self.settings = settings
        self.clock = clock
        self.service_names = services if services is not None else {s.value: s for s in Service}
        self.core: ClientCore | None = None
        self.timer: CoreTimer | None = None
        self._handover = Intake(asyncio.get_running_loop())
        self._put_event = self._handover.channel("client events", self._on_event, capacity=4096)
        # a client that subscribes to every channel of a fleet of 100 sends 1,500 subscriptions at once; none may be lost
        self._put_subscription = self._handover.channel("subscriptions", self._on_subscription, capacity=65536)
        self._put_call = self._handover.channel("service calls", self._on_call, capacity=256)
        self._put_set = self._handover.channel("parameter sets", self._on_params_set, capacity=256)
        #: Who watches which topic (set by :meth:`watch_with`); None: every key is followed.
        self.watch: Watch | None = None
        self.viewer: Viewer | None = None
        self.params: Parameters | None = None
        #: The parameters as the SDK's threads answer getParameters from: replaced whole on the loop, read whole there.
        self._param_snapshot: list[Any] = []
        self._sets: dict[int, ParamsSetIn] = {}
        self._timed: list[Any] = []
        self._connections: dict[str, _Connection] = {}
        self._by_client: dict[int, _Connection] = {}
        self._calls: dict[int, _Call] = {}
        self._numbers = itertools.count(1)
        #: (client, call id) of the calls the view's handler took: their failures are the view's, reported by the core.
        self._our_calls: set[tuple[int, int]] = set()
        self._inflight: set[concurrent.futures.Future[bytes]] = set()
        self._front: asyncio.Server | None = None
        listener = _listener(self._put_event, self._put_subscription, self._get_params, self._set_params)
        self.server = start_server(settings, listener, self._services())
        self.port = settings.port
        self.url = url(settings.host, settings.port)
        self._writer: Any = None
        if settings.mcap:
            try:
                self._writer = foxglove.open_mcap(settings.mcap, allow_overwrite=True)
            except Exception as exc:
                self.server.stop()
                raise ConfigError(f"cannot write {settings.mcap}: {exc}") from None

    def _services(self) -> list[Any]:
        import foxglove

        def schema(spec: dict[str, Any]) -> Any:
            data = foxglove.Schema(name=spec["title"], encoding="jsonschema", data=json.dumps(spec).encode())
            return foxglove.MessageSchema(encoding=CLIENT_ENCODING, schema=data)

        return [
            foxglove.Service(
                name,
                schema=foxglove.ServiceSchema(
                    SERVICE_SPECS[service].type,
                    request=schema(SERVICE_SPECS[service].request),
                    response=schema(SERVICE_SPECS[service].response),
                ),
                handler=self._handle_call,
            )
            for name, service in self.service_names.items()
        ]

    async def start(self) -> None:
        """Listen where clients connect (``--host``/``--port``)."""
        host, port = self.settings.host, self.settings.port
        try:
            self._front = await asyncio.start_server(self._serve_client, host, port, limit=HEAD_LIMIT)
        except OSError as exc:
            self.close()
            raise ConfigError(
                f"cannot serve Foxglove on {host}:{port} ({exc.strerror or exc}); is another server on that port? try --port 0 or another port"
            ) from None
        self.port = int(self._front.sockets[0].getsockname()[1])
        self.url = url(host, self.port)

    def attach(self, core: ClientCore, *timed: Timed) -> None:
        """Feed ``core`` from now on, and run its timers and those of ``timed`` (until :meth:`close`)."""
        self.core = core
        self._timed = [core, *timed]
        self.timer = CoreTimer(_Together(self._timed), self.clock)
        self.timer.start()

    def watch_with(self, watch: Watch, viewer: Viewer) -> None:
        """Follow the clients' subscriptions in ``watch`` and tell ``viewer`` (before any client connects)."""
        self.watch, self.viewer = watch, viewer

    def serve_params(self, params: Parameters, robots: ParamsRobots) -> None:
        """Answer the clients' getParameters and setParameters from ``params``; what it asks of a gateway goes to ``robots``."""
        self.params, self._params_robots = params, robots

    async def run(self, stop: asyncio.Event) -> None:
        """Serve until ``stop``: the view's handlers run on the loop as the edge hands payloads over, the core's timers on the loop's timer."""
        await stop.wait()

    def close(self) -> None:
        if self.timer is not None:
            self.timer.stop()
        if self._front is not None:
            self._front.close()
            self._front = None
        for connection in list(self._connections.values()):
            connection.close()
        for future in list(self._inflight):
            if not future.done():
                future.set_exception(ServiceFailure("blackmetal foxglove is stopping"))
        for request in self._sets.values():
            if not request.future.done():
                request.future.set_exception(ServiceFailure("blackmetal foxglove is stopping"))
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        self.server.stop()

    def poke(self) -> None:
        """An input reached the core (from outside the host too): move its timer if its deadline came earlier."""
        if self.timer is not None:
            self.timer.poke()

    # --------------------------------------------------------------- the front
    async def _serve_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        upstream: asyncio.StreamWriter | None = None
        connection: _Connection | None = None
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HANDSHAKE_TIMEOUT_S)
            head, shown = rewrite_request(head)
            up_reader, upstream = await asyncio.open_connection(INNER_HOST, self.server.port, limit=HEAD_LIMIT)
            upstream.write(head)
            answer = await asyncio.wait_for(up_reader.readuntil(b"\r\n\r\n"), HANDSHAKE_TIMEOUT_S)
            upgraded = switches_protocols(answer)
            writer.write(rewrite_response(answer, shown) if upgraded and shown else answer)
            if not upgraded:  # the server's refusal, as it sent it
                await self._copy(up_reader, writer)
                return
            connection = _Connection(secrets.token_hex(8), writer, upstream, self._on_server_text)
            self._connections[connection.token] = connection
            upstream.write(ws_frame(OP_TEXT, marker_advertisement(connection.token), mask=os.urandom(4)))
            pumps = {
                asyncio.ensure_future(self._copy(reader, upstream)),
                asyncio.ensure_future(self._downstream(connection, up_reader)),
            }
            _, pending = await asyncio.wait(pumps, return_when=asyncio.FIRST_COMPLETED)
            for task in pending:
                task.cancel()
            await asyncio.gather(*pending, return_exceptions=True)
        except (OSError, EOFError, asyncio.LimitOverrunError, TimeoutError):
            pass  # a client that left or never spoke WebSocket: nothing to keep
        finally:
            for stream in (writer, upstream):
                if stream is not None:
                    stream.close()
            if connection is not None:
                self._connections.pop(connection.token, None)
                if connection.client is not None:
                    self._by_client.pop(connection.client, None)
                    if self.core is not None:
                        self.core.on_client_gone(connection.client, self.clock())
                        self.poke()
                    if self.watch is not None and self.viewer is not None and self.watch.client_gone(connection.client):
                        self.viewer.watch_changed()  # the SDK says so too, subscription by subscription; this is the same end, once

    @staticmethod
    async def _copy(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        while data := await reader.read(READ_SIZE):
            writer.write(data)
            await writer.drain()

    async def _downstream(self, connection: _Connection, reader: asyncio.StreamReader) -> None:
        """Server -> client, unchanged; the view's status messages go in between two messages."""
        writer = connection.writer
        while data := await reader.read(READ_SIZE):
            connection.busy = True
            try:
                boundaries = connection.tap.feed(data)
                start = 0
                if connection.outbox and boundaries:
                    writer.write(data[: boundaries[0]])
                    connection.flush()
                    start = boundaries[0]
                writer.write(data[start:] if start else data)
                if connection.outbox and connection.tap.at_boundary:
                    connection.flush()
            finally:
                connection.busy = False
            await writer.drain()

    def _on_server_text(self, connection: _Connection, text: bytes) -> None:
        """A JSON message the SDK sent a client: its own refusals are reported (the view's own failures already are)."""
        try:
            op = _server_op.decode(text)
        except (msgspec.DecodeError, msgspec.ValidationError):
            return
        if self.core is None:
            return
        kind = next((k for k in ServerRefusal if k.value == op.op), None)
        if kind is ServerRefusal.STATUS and op.level < StatusLevel.WARNING:
            return
        if kind is ServerRefusal.SERVICE_CALL_FAILURE:
            if connection.client is not None and op.call_id is not None and (connection.client, op.call_id) in self._our_calls:
                self._our_calls.discard((connection.client, op.call_id))
                return
            message = f"{op.message} (service id {op.service_id}, call {op.call_id})"
        elif kind is ServerRefusal.STATUS:
            message = op.message
        else:
            return
        self.core.on_server_refusal(connection.client, kind, message, self.clock())
        self.poke()

    # --------------------------------------------------------------- from the SDK's threads, on the loop
    def _on_event(self, event: ClientEvent) -> None:
        if event.channel == MARKER_CHANNEL_ID:
            connection = self._connections.get(event.schema_name) if event.kind is EventKind.ADVERTISE else None
            if connection is not None and event.topic == MARKER_TOPIC and connection.client is None:
                connection.client = event.client
                self._by_client[event.client] = connection
            if event.client in self._by_client:
                return  # the marker of a connection through the front
        core = self.core
        if core is None:
            return
        now = self.clock()
        if event.kind is EventKind.ADVERTISE:
            core.on_advertise(event.client, event.channel, event.topic, event.encoding, event.schema_name, now)
        elif event.kind is EventKind.UNADVERTISE:
            core.on_unadvertise(event.client, event.channel, now)
        else:
            core.on_message(event.client, event.channel, event.data, now)
        self.poke()

    def _on_subscription(self, event: ClientEvent) -> None:
        watch, viewer = self.watch, self.viewer
        if watch is None or viewer is None:
            return
        if event.kind is EventKind.SUBSCRIBE:
            first = watch.subscribe(event.client, event.topic)
            viewer.subscribed(event.topic)
            changed = first
        else:
            changed = watch.unsubscribe(event.client, event.topic)
        if changed:
            viewer.watch_changed()
        self.poke()

    # --------------------------------------------------------------- parameters
    def _get_params(self, names: list[str]) -> list[Any]:
        """getParameters, on an SDK thread: from the snapshot the loop last made (a list replaced whole, never changed)."""
        snapshot = self._param_snapshot
        if not names:
            return snapshot
        wanted = set(names)
        return [param for param in snapshot if param.name in wanted]

    def _set_params(self, client: int, parameters: list[Any]) -> list[Any]:
        """setParameters, on an SDK thread: hand it to the loop, wait (bounded) for the gateways' answer, answer with the values then."""
        future: concurrent.futures.Future[list[Param]] = concurrent.futures.Future()
        values = [(p.name, p.get_value()) for p in parameters]
        try:
            self._put_set(ParamsSetIn(client, values, future))
            answer = future.result(timeout=self.settings.call_timeout + CALL_MARGIN_S)
        except (concurrent.futures.TimeoutError, concurrent.futures.CancelledError, ServiceFailure):
            return self._get_params([name for name, _ in values])  # the values the view knows: nothing it did not see changed
        return [foxglove_parameter(param) for param in answer]

    def _on_params_set(self, request: ParamsSetIn) -> None:
        if self.params is None:
            request.future.set_exception(ServiceFailure("blackmetal foxglove serves no parameters yet"))
            return
        number = next(self._numbers)
        self._sets[number] = request
        self.params.on_set(number, request.client, request.values, self.clock())
        self.poke()

    # ParamsOutput
    def ask_params(self, robot_id: str) -> None:
        self._params_robots.ask_params(robot_id)

    def set_params(self, robot_id: str, call: int, payload: bytes) -> None:
        self._params_robots.set_params(robot_id, call, payload)

    def report(self, robot_id: str | None, topic: str, reason: str, text: str, now: float) -> None:
        self._params_robots.report(robot_id, topic, reason, text, now)

    def parameters_answer(self, call: int, values: list[Param]) -> None:
        request = self._sets.pop(call, None)
        if request is not None and not request.future.done():
            request.future.set_result(values)

    def parameters_changed(self, values: list[Param]) -> None:
        """A gateway's table changed: the snapshot is made anew and the changed values go to the clients that follow them."""
        if self.params is not None:
            self._param_snapshot = [foxglove_parameter(param) for param in self.params.values()]
        self.server.publish_parameter_values([foxglove_parameter(param) for param in values])

    def on_params_table(self, robot_id: str, payload: bytes) -> GatewayParams | None:
        """A gateway's parameter table arrived (published, or answered); the table, if it decoded."""
        return self.params.on_table(robot_id, payload, self.clock()) if self.params is not None else None

    def on_params_reply(self, robot_id: str, reply: tuple[int, bytes | None, bytes | None]) -> None:
        if self.params is not None:
            call, ok, err = reply
            self.params.on_set_reply(robot_id, call, ok, err, self.clock())
            self.poke()

    def _handle_call(self, request: Any) -> bytes:
        """The SDK's service handler, on its blocking thread: hand the call over and wait for the core's answer (bounded)."""
        future: concurrent.futures.Future[bytes] = concurrent.futures.Future()
        self._inflight.add(future)
        self._our_calls.add((request.client_id, request.call_id))
        try:
            self._put_call(ServiceCallIn(request.service_name, request.client_id, request.call_id, bytes(request.payload), future))
            return future.result(timeout=self.settings.call_timeout + CALL_MARGIN_S)
        except concurrent.futures.TimeoutError:
            raise ServiceFailure(f"no answer within {self.settings.call_timeout + CALL_MARGIN_S:g} s") from None
        finally:
            self._inflight.discard(future)

    def _on_call(self, call: ServiceCallIn) -> None:
        core = self.core
        if core is None:
            call.future.set_exception(ServiceFailure("blackmetal foxglove is not ready yet"))
            return
        number = next(self._numbers)
        self._calls[number] = _Call(call.client, call.call_id, call.future)
        core.on_service_call(number, call.client, call.service, call.payload, self.clock())
        self.poke()

    # --------------------------------------------------------------- to the clients (ControlsOutput's other half: the robot's keys are its port's)
    def status(self, client: int | None, level: StatusLevel, message: str) -> None:
        """A status message to that client; to every client when it is not known (a client that did not come through the front)."""
        connection = self._by_client.get(client) if client is not None else None
        if connection is not None:
            connection.send(ws_frame(OP_TEXT, status_message(level, message)))
            return
        import foxglove

        levels = {
            StatusLevel.INFO: foxglove.StatusLevel.Info,
            StatusLevel.WARNING: foxglove.StatusLevel.Warning,
            StatusLevel.ERROR: foxglove.StatusLevel.Error,
        }
        self.server.publish_status(message, levels[level])

    def answer(self, call: int, response: bytes | None, failure: str | None) -> None:
        pending = self._calls.pop(call, None)
        if pending is None or pending.future.done():
            return
        if failure is None:
            self._our_calls.discard((pending.client, pending.call_id))
            pending.future.set_result(response or b"")
        else:
            pending.future.set_exception(ServiceFailure(failure))
