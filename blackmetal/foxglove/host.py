"""The Foxglove view's host: the WebSocket server the app connects to (behind :mod:`.front`) and, with ``--mcap``, the MCAP file.

It feeds the controls what clients publish and call, stamped with the clock, on the loop only; it closes what it opened in reverse order.
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
from dataclasses import dataclass
from functools import partial
from operator import call as run
from typing import Any

import msgspec

from blackmetal.runtime.driver import Core, CoreTimer
from blackmetal.runtime.intake import Intake
from blackmetal.schemas import ConfigError, Param

from .controls import Controls, FleetControls
from .front import (
    HANDSHAKE_TIMEOUT_S,
    HEAD_LIMIT,
    INNER_HOST,
    MARKER_CHANNEL_ID,
    MARKER_TOPIC,
    OP_TEXT,
    READ_SIZE,
    Connection,
    first_message,
    marker_advertisement,
    rewrite_request,
    rewrite_response,
    server_op,
    status_message,
    switches_protocols,
    url,
    ws_frame,
)
from .naming import CLIENT_ENCODING, SERVICE_SPECS, ServerRefusal, Service, StatusLevel
from .params import Parameters
from .sdk import CALL_MARGIN_S, ServiceFailure, foxglove_parameter, sdk_listener, start_server
from .settings import FoxgloveSettings
from .zenoh_edge import Wired

#: What the host feeds with the clients' doings: one robot's controls, or a fleet's.
ClientCore = Controls | FleetControls


@dataclass(slots=True)
class _Together:
    """Several timed parts as one for the host's one timer."""

    parts: list[Core]

    def tick(self, now: float) -> None:
        for part in self.parts:
            part.tick(now)

    def next_deadline(self) -> float:
        return min(part.next_deadline() for part in self.parts)


class FoxgloveHost:
    """The front, the SDK server (and the MCAP file) of one view; feeds :class:`Controls`; :meth:`close` stops them, the file first."""

    def __init__(
        self, settings: FoxgloveSettings, clock: Callable[[], float] = time.monotonic, services: dict[str, Service] | None = None
    ) -> None:
        """``services``: the name each service is advertised under (a fleet's ``/r3/set_estop``, ...)."""
        import foxglove

        self.settings = settings
        self.clock = clock
        self.service_names = services if services is not None else {s.value: s for s in Service}
        self.core: ClientCore | None = None
        self.timer: CoreTimer | None = None
        self._handover = Intake(asyncio.get_running_loop())
        self._put_event = self._handover.channel("client events", run, capacity=4096)
        # a client that subscribes to every channel of a fleet of 100 sends 1,500 subscriptions at once; none may be lost
        self._put_subscription = self._handover.channel("subscriptions", run, capacity=65536)
        self._put_call = self._handover.channel("service calls", run, capacity=256)
        self._put_set = self._handover.channel("parameter sets", run, capacity=256)
        self.viewer: Wired | None = None
        self.params: Parameters | None = None
        #: The parameters as the SDK's threads answer getParameters from: replaced whole on the loop, read whole there.
        self._param_snapshot: list[Any] = []
        self._sets: dict[int, concurrent.futures.Future[list[Param]]] = {}
        self._connections: dict[str, Connection] = {}
        self._by_client: dict[int, Connection] = {}
        #: The host's number of a call -> (client, its call id, the SDK thread's future).
        self._calls: dict[int, tuple[int, int, concurrent.futures.Future[bytes]]] = {}
        self._numbers = itertools.count(1)
        #: (client, call id) of the calls the view's handler took: their failures are the view's, reported by the core.
        self._our_calls: set[tuple[int, int]] = set()
        self._inflight: set[concurrent.futures.Future[bytes]] = set()
        self._front: asyncio.Server | None = None
        listener = sdk_listener(self, self._put_event, self._put_subscription, self._get_params, self._set_params)

        def schema(spec: dict[str, Any]) -> Any:
            data = foxglove.Schema(name=spec["title"], encoding="jsonschema", data=json.dumps(spec).encode())
            return foxglove.MessageSchema(encoding=CLIENT_ENCODING, schema=data)

        advertised = [
            foxglove.Service(
                name,
                schema=foxglove.ServiceSchema(spec.type, request=schema(spec.request), response=schema(spec.response)),
                handler=self._handle_call,
            )
            for name, spec in ((name, SERVICE_SPECS[service]) for name, service in self.service_names.items())
        ]
        self.server = start_server(settings, listener, advertised)
        self.port = settings.port
        self.url = url(settings.host, settings.port)
        self._writer: Any = None
        if settings.mcap:
            try:
                self._writer = foxglove.open_mcap(settings.mcap, allow_overwrite=True)
            except Exception as exc:
                self.server.stop()
                raise ConfigError(f"cannot write {settings.mcap}: {exc}") from None

    async def start(self) -> None:
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

    def attach(self, core: ClientCore, params: Parameters, viewer: Wired, *timed: Core) -> None:
        """Feed ``core`` and ``params`` (their gateways: ``viewer``), tell ``viewer`` the clients' subscriptions,
        and run the timers of all and of ``timed`` (until :meth:`close`)."""
        self.core, self.params, self.viewer = core, params, viewer
        params.gateways = viewer
        self.timer = CoreTimer(_Together([core, params, *timed]), self.clock)
        self.timer.start()

    def close(self) -> None:
        if self.timer is not None:
            self.timer.stop()
        if self._front is not None:
            self._front.close()
            self._front = None
        for connection in list(self._connections.values()):
            connection.close()
        futures: list[concurrent.futures.Future[Any]] = [*self._inflight, *self._sets.values()]
        for future in futures:
            if not future.done():
                future.set_exception(ServiceFailure("blackmetal foxglove is stopping"))
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        self.server.stop()

    def poke(self) -> None:
        if self.timer is not None:
            self.timer.poke()

    async def _serve_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        upstream: asyncio.StreamWriter | None = None
        connection: Connection | None = None
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HANDSHAKE_TIMEOUT_S)
            head, shown = rewrite_request(head)
            up_reader, upstream = await asyncio.open_connection(INNER_HOST, self.server.port, limit=HEAD_LIMIT)
            upstream.write(head)
            answer = await asyncio.wait_for(up_reader.readuntil(b"\r\n\r\n"), HANDSHAKE_TIMEOUT_S)
            upgraded = switches_protocols(answer)
            writer.write(rewrite_response(answer, shown) if upgraded and shown else answer)
            if not upgraded:  # the server's refusal, as it sent it
                return await self._copy(up_reader, writer)
            writer.write(await asyncio.wait_for(first_message(up_reader), HANDSHAKE_TIMEOUT_S))
            connection = Connection(secrets.token_hex(8), writer, upstream, self._on_server_text)
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
                    if self.viewer is not None and self.viewer.watch.client_gone(connection.client):
                        self.viewer.watch_changed()  # the SDK says so too, subscription by subscription; this is the same end, once

    @staticmethod
    async def _copy(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        while data := await reader.read(READ_SIZE):
            writer.write(data)
            await writer.drain()

    async def _downstream(self, connection: Connection, reader: asyncio.StreamReader) -> None:
        """Server -> client, unchanged; the view's status messages go between two messages."""
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

    def _on_server_text(self, connection: Connection, text: bytes) -> None:
        """The SDK's own refusals to a client are reported (the view's own failures already are)."""
        try:
            op = server_op.decode(text)
        except (msgspec.DecodeError, msgspec.ValidationError):
            return
        if self.core is None:
            return
        if op.op == ServerRefusal.STATUS.value and op.level >= StatusLevel.WARNING:
            kind, message = ServerRefusal.STATUS, op.message
        elif op.op == ServerRefusal.SERVICE_CALL_FAILURE.value:
            if connection.client is not None and op.call_id is not None and (connection.client, op.call_id) in self._our_calls:
                self._our_calls.discard((connection.client, op.call_id))
                return
            kind, message = ServerRefusal.SERVICE_CALL_FAILURE, f"{op.message} (service id {op.service_id}, call {op.call_id})"
        else:
            return
        self.core.on_server_refusal(connection.client, kind, message, self.clock())
        self.poke()

    def client_advertised(self, client: int, channel: int, topic: str, encoding: str, schema_name: str) -> None:
        if channel == MARKER_CHANNEL_ID:
            connection = self._connections.get(schema_name)
            if connection is not None and topic == MARKER_TOPIC and connection.client is None:
                connection.client = client
                self._by_client[client] = connection
        self._to_core(client, channel, lambda core, now: core.on_advertise(client, channel, topic, encoding, schema_name, now))

    def client_unadvertised(self, client: int, channel: int) -> None:
        self._to_core(client, channel, lambda core, now: core.on_unadvertise(client, channel, now))

    def client_published(self, client: int, channel: int, data: bytes) -> None:
        self._to_core(client, channel, lambda core, now: core.on_message(client, channel, data, now))

    def _to_core(self, client: int, channel: int, act: Callable[[ClientCore, float], None]) -> None:
        if channel == MARKER_CHANNEL_ID and client in self._by_client:
            return  # the marker of a connection through the front
        if self.core is not None:
            act(self.core, self.clock())
            self.poke()

    def client_subscribed(self, client: int, topic: str, subscribed: bool) -> None:
        viewer = self.viewer
        if viewer is None:
            return
        if subscribed:
            changed = viewer.watch.subscribe(client, topic)
            viewer.subscribed(topic)
        else:
            changed = viewer.watch.unsubscribe(client, topic)
        if changed:
            viewer.watch_changed()
        self.poke()

    def _get_params(self, names: list[str]) -> list[Any]:
        """getParameters, on an SDK thread: from the loop's last snapshot (a list replaced whole, never changed)."""
        snapshot, wanted = self._param_snapshot, set(names)
        return [param for param in snapshot if param.name in wanted] if names else snapshot

    def _set_params(self, client: int, parameters: list[Any]) -> list[Any]:
        """setParameters, on an SDK thread: handed to the loop; waits (bounded) for the gateways' answer."""
        future: concurrent.futures.Future[list[Param]] = concurrent.futures.Future()
        values = [(p.name, p.get_value()) for p in parameters]
        try:
            self._put_set(partial(self._on_params_set, client, values, future))
            answer = future.result(timeout=self.settings.call_timeout + CALL_MARGIN_S)
        except (concurrent.futures.TimeoutError, concurrent.futures.CancelledError, ServiceFailure):
            return self._get_params([name for name, _ in values])  # the values the view knows: nothing it did not see changed
        return [foxglove_parameter(param) for param in answer]

    def _on_params_set(self, client: int, values: list[tuple[str, object]], future: concurrent.futures.Future[list[Param]]) -> None:
        if self.params is None:
            return future.set_exception(ServiceFailure("blackmetal foxglove serves no parameters yet"))
        number = next(self._numbers)
        self._sets[number] = future
        self.params.on_set(number, client, values, self.clock())
        self.poke()

    def parameters_answer(self, call: int, values: list[Param]) -> None:
        future = self._sets.pop(call, None)
        if future is not None and not future.done():
            future.set_result(values)

    def parameters_changed(self, values: list[Param]) -> None:
        if self.params is not None:
            self._param_snapshot = [foxglove_parameter(param) for param in self.params.values()]
        self.server.publish_parameter_values([foxglove_parameter(param) for param in values])

    def _handle_call(self, request: Any) -> bytes:
        """The SDK's service handler, on its own thread: waits (bounded) for the core's answer."""
        future: concurrent.futures.Future[bytes] = concurrent.futures.Future()
        self._inflight.add(future)
        self._our_calls.add((request.client_id, request.call_id))
        try:
            self._put_call(partial(self._on_call, request.service_name, request.client_id, request.call_id, bytes(request.payload), future))
            return future.result(timeout=self.settings.call_timeout + CALL_MARGIN_S)
        except concurrent.futures.TimeoutError:
            raise ServiceFailure(f"no answer within {self.settings.call_timeout + CALL_MARGIN_S:g} s") from None
        finally:
            self._inflight.discard(future)

    def _on_call(self, service: str, client: int, call_id: int, payload: bytes, future: concurrent.futures.Future[bytes]) -> None:
        core = self.core
        if core is None:
            return future.set_exception(ServiceFailure("blackmetal foxglove is not ready yet"))
        number = next(self._numbers)
        self._calls[number] = (client, call_id, future)
        core.on_service_call(number, client, service, payload, self.clock())
        self.poke()

    def status(self, client: int | None, level: StatusLevel, message: str) -> None:
        """To that client; to every client when it is not known (it did not come through the front)."""
        connection = self._by_client.get(client) if client is not None else None
        if connection is not None:
            return connection.send(ws_frame(OP_TEXT, status_message(level, message)))
        import foxglove

        self.server.publish_status(message, getattr(foxglove.StatusLevel, level.name.title()))  # INFO -> Info, ...

    def answer(self, call: int, response: bytes | None, failure: str | None) -> None:
        client, call_id, future = self._calls.pop(call, (0, 0, None))
        if future is None or future.done():
            return
        if failure is None:
            self._our_calls.discard((client, call_id))
            future.set_result(response or b"")
        else:
            future.set_exception(ServiceFailure(failure))
