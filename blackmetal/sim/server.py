"""TCP edge of the simulated robot: control port and log port.

One control client at a time: a new one takes over (the robot's side of a reconnect whose old socket is
half dead); any number of log clients. Link faults are each client's :class:`ControlSession`'s.
"""

from __future__ import annotations

import asyncio
import errno
import logging
import time
from collections.abc import Awaitable, Callable
from contextlib import suppress
from dataclasses import dataclass, field

from blackmetal import robot_model as model
from blackmetal import wire
from blackmetal.transport import ByteStream, nodelay, serve_tcp

from .control import ControlSession, ReplySink
from .physics import SimRobot

log = logging.getLogger("blackmetal.sim")


@dataclass(eq=False)
class SimServer:
    robot: SimRobot
    host: str = "127.0.0.1"
    control_port: int = model.CONTROL_PORT
    log_port: int = model.LOG_PORT
    log_interval: float = 1.0
    clock: Callable[[], float] = time.monotonic
    state: int = field(default=1, init=False)  # READY: the real robot only ever reports READY ...
    direction: int = field(default=1, init=False)  # ... and NORTH
    malformed_requests: int = field(default=0, init=False)
    _servers: list[asyncio.Server] = field(default_factory=list, init=False)
    _control: ControlSession | None = field(default=None, init=False)
    _log_streams: set[ByteStream] = field(default_factory=set, init=False)
    _tasks: set[asyncio.Task[None]] = field(default_factory=set, init=False)
    _closing: asyncio.Event = field(default_factory=asyncio.Event, init=False)

    async def start(self) -> None:
        """Bind both ports (0 = pick a free one; the bound ports replace 0)."""
        loop = asyncio.get_running_loop()
        control = await self._listen("control", lambda: loop.create_server(lambda: _ControlProtocol(self), self.host, self.control_port))
        try:
            logs = await self._listen("log", lambda: serve_tcp(self.host, self.log_port, self.serve_log))
        except OSError:
            control.close()
            raise
        self._servers = [control, logs]
        self.control_port = control.sockets[0].getsockname()[1]
        self.log_port = logs.sockets[0].getsockname()[1]

    async def _listen(self, port_name: str, listen: Callable[[], Awaitable[asyncio.Server]]) -> asyncio.Server:
        """``listen()``'s server, or OSError whose text is one sentence naming the port and what to do (no errno)."""
        port = self.control_port if port_name == "control" else self.log_port
        try:
            return await listen()
        except OSError as exc:
            reasons = {
                errno.EADDRINUSE: "the port is in use by another process (another simulator or robot?)",
                errno.EADDRNOTAVAIL: f"{self.host} is not an address of this machine",
                errno.EACCES: "ports below 1024 need root (the real robot's 665/664); use others, or 0 for free ones",
            }
            why = reasons.get(exc.errno or 0) or exc.strerror or str(exc)
            raise OSError(
                f"cannot listen on {self.host}:{port} (the {port_name} port): {why}; choose another with --{port_name}-port PORT (0 picks a free one)"
            ) from None

    @property
    def closed(self) -> bool:
        return self._closing.is_set()

    async def close(self) -> None:
        """Stop listening and close every client; handlers end by themselves."""
        self._closing.set()
        for server in self._servers:
            server.close()
        self.drop_clients()
        if self._tasks:
            await asyncio.wait(self._tasks, timeout=1.0)
        for task in list(self._tasks):
            task.cancel()  # last resort
        for server in self._servers:
            with suppress(TimeoutError):
                await asyncio.wait_for(server.wait_closed(), timeout=1.0)

    def drop_clients(self) -> None:
        """Close every client connection, as a robot that lost its network would."""
        if self._control is not None:
            self._control.close()
            self._control = None
        for stream in list(self._log_streams):
            stream.close()
        self._log_streams.clear()

    def _track(self) -> None:
        task = asyncio.current_task()
        if task is not None:
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

    async def serve_control(self, stream: ByteStream) -> None:
        """Serve one control client on ``stream`` (a memory pipe; TCP clients are served by :class:`_ControlProtocol`)."""
        self._track()
        session = self._open_control(stream)
        try:
            await stream.pump(session.feed)
        except ConnectionError:
            pass  # a handler ends quietly; the server logs nothing for a closed client
        finally:
            self._close_control(session)

    def _open_control(self, sink: ReplySink) -> ControlSession:
        """A new control client: it takes over from the one before, whose connection is closed."""
        if self._control is not None:
            log.info("new control client takes over from the old one")
            self._control.close()
        self._control = ControlSession(self.robot, sink, self.clock, asyncio.get_running_loop(), self._count_malformed)
        return self._control

    def _close_control(self, session: ControlSession) -> None:
        if self._control is session:
            self._control = None
        session.close()

    def _count_malformed(self) -> None:
        self.malformed_requests += 1

    async def serve_log(self, writer: ByteStream) -> None:
        self._track()
        self._log_streams.add(writer)
        try:
            while not writer.is_closing():
                if not self.robot.faults.silent:
                    writer.write(wire.encode_log_report(self.state, self.direction))
                    await writer.drain()
                with suppress(TimeoutError):
                    await asyncio.wait_for(self._closing.wait(), self.log_interval)
        except ConnectionError:
            pass
        finally:
            self._log_streams.discard(writer)
            writer.close()


class _ControlProtocol(asyncio.Protocol):
    """A TCP control client, served by callbacks: each read goes straight to its :class:`ControlSession`."""

    def __init__(self, server: SimServer) -> None:
        self._server = server
        self._session: ControlSession | None = None
        self._transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = nodelay(transport)
        self._session = self._server._open_control(self._transport)

    def data_received(self, data: bytes) -> None:
        if self._session is not None:
            self._session.feed(data)

    def connection_lost(self, exc: Exception | None) -> None:
        if self._session is not None:
            self._server._close_control(self._session)

    # a client that does not read its replies stops the robot reading its requests, as a full socket would
    def pause_writing(self) -> None:
        if self._transport is not None:
            self._transport.pause_reading()

    def resume_writing(self) -> None:
        if self._transport is not None and not self._transport.is_closing():
            self._transport.resume_reading()
