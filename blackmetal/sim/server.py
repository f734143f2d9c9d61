"""TCP edge of the simulated robot: control port and log port, with link faults.

One control client at a time: a new connection takes over from the old one
(the robot's side of a reconnect whose old socket is half dead). Any number
of log-port clients each get a state report about once a second. Link
faults (delay, garbage, glued and split writes, dropped connections,
silence) are applied here; sensor faults live in :class:`SimRobot`.
"""

from __future__ import annotations

import asyncio
import errno
import logging
import time
from collections.abc import Callable
from typing import Any

from blackmetal import robot_model as model
from blackmetal import wire
from blackmetal.transport import ByteStream, TcpStream
from blackmetal.wire import Malformed

from .physics import SimRobot

log = logging.getLogger("blackmetal.sim")

#: How long a reply held back to be glued to the next one may wait (s).
GLUE_HOLD_S = 0.05


class SimServer:
    """Serves one :class:`SimRobot` on a control port and a log port."""

    def __init__(
        self,
        robot: SimRobot,
        host: str = "127.0.0.1",
        control_port: int = model.CONTROL_PORT,
        log_port: int = model.LOG_PORT,
        log_interval: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.robot = robot
        self.host = host
        self.control_port = control_port
        self.log_port = log_port
        self.log_interval = log_interval
        self.clock = clock
        self.state = 1  # READY: the real robot only ever reports READY ...
        self.direction = 1  # ... and NORTH
        self.connections = 0
        self.malformed_requests = 0
        self._servers: list[asyncio.base_events.Server] = []
        self._control_stream: ByteStream | None = None
        self._log_streams: set[ByteStream] = set()
        self._tasks: set[asyncio.Task[None]] = set()
        self._held = bytearray()
        self._flush_handle: asyncio.TimerHandle | None = None
        self._closing = asyncio.Event()

    async def start(self) -> None:
        """Bind both ports (0 = pick a free one; the bound ports replace 0)."""
        control = await self._listen("control", self.serve_control, self.control_port)
        try:
            logs = await self._listen("log", self.serve_log, self.log_port)
        except OSError:
            control.close()
            raise
        self._servers = [control, logs]
        self.control_port = control.sockets[0].getsockname()[1]
        self.log_port = logs.sockets[0].getsockname()[1]

    async def _listen(self, port_name: str, serve: Callable[[ByteStream], Any], port: int) -> asyncio.Server:
        """A listening server, or OSError whose text is one sentence naming the port and what to do (no errno)."""
        try:
            return await asyncio.start_server(lambda r, w: serve(TcpStream(r, w)), self.host, port)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                why = "the port is in use by another process (another simulator or robot?)"
            elif exc.errno == errno.EADDRNOTAVAIL:
                why = f"{self.host} is not an address of this machine"
            elif exc.errno == errno.EACCES:
                why = "ports below 1024 need root (the real robot's 665/664); use others, or 0 for free ones"
            else:
                why = exc.strerror or str(exc)
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
            try:
                await asyncio.wait_for(server.wait_closed(), timeout=1.0)
            except TimeoutError:
                pass

    def drop_clients(self) -> None:
        """Close every client connection, as a robot that lost its network would."""
        if self._control_stream is not None:
            self._control_stream.close()
            self._control_stream = None
        for stream in list(self._log_streams):
            stream.close()
        self._log_streams.clear()

    def _track(self) -> None:
        task = asyncio.current_task()
        if task is not None:
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

    # ------------------------------------------------------------------ control port

    async def serve_control(self, writer: ByteStream) -> None:
        """Serve one control client on ``writer`` (a ByteStream: TCP, or a memory pipe)."""
        self._track()
        if self._control_stream is not None:
            log.info("new control client takes over from the old one")
            self._control_stream.close()
        self._control_stream = writer
        self._held.clear()
        self.connections += 1
        decoder = wire.RequestDecoder()
        try:
            while True:
                data = await writer.read(4096)
                if not data:
                    break
                for item in decoder.feed(data):
                    if isinstance(item, Malformed):
                        self.malformed_requests += 1
                        log.warning("ignoring malformed request: %s", item.reason)
                        continue
                    faults = self.robot.faults
                    if faults.disconnect and self.robot.rng.random() < faults.disconnect:
                        log.info("fault: dropping the control connection")
                        writer.close()
                        return
                    replies = self.robot.handle(item, self.clock())
                    if faults.silent:
                        continue
                    if faults.delay:
                        await asyncio.sleep(faults.delay)
                    if writer.is_closing():
                        return
                    await self._write_replies(writer, b"".join(replies))
        except (ConnectionError, asyncio.IncompleteReadError):
            pass  # a handler ends quietly; the server logs nothing for a closed client
        finally:
            if self._control_stream is writer:
                self._control_stream = None
            writer.close()

    async def _write_replies(self, writer: ByteStream, data: bytes) -> None:
        faults = self.robot.faults
        rng = self.robot.rng
        if faults.garbage and rng.random() < faults.garbage:
            data = rng.randbytes(rng.randint(1, 24)) + data
        if faults.glue and rng.random() < faults.glue:
            self._held += data  # sent together with the next replies
            if self._flush_handle is None:
                self._flush_handle = asyncio.get_running_loop().call_later(GLUE_HOLD_S, self._flush_held, writer)
            return
        if self._held:
            data = bytes(self._held) + data
            self._held.clear()
        if faults.split and len(data) > 1 and rng.random() < faults.split:
            cut = rng.randint(1, len(data) - 1)
            writer.write(data[:cut])
            await writer.drain()
            await asyncio.sleep(0.002)
            data = data[cut:]
        writer.write(data)
        await writer.drain()

    def _flush_held(self, writer: ByteStream) -> None:
        self._flush_handle = None
        if self._held and not writer.is_closing():
            writer.write(bytes(self._held))
        self._held.clear()

    # ------------------------------------------------------------------ log port

    async def serve_log(self, writer: ByteStream) -> None:
        """Push a state report about once a second to one log client."""
        self._track()
        self._log_streams.add(writer)
        try:
            while not writer.is_closing():
                if not self.robot.faults.silent:
                    writer.write(wire.encode_log_report(self.state, self.direction))
                    await writer.drain()
                try:
                    await asyncio.wait_for(self._closing.wait(), self.log_interval)
                except TimeoutError:
                    pass
        except ConnectionError:
            pass
        finally:
            self._log_streams.discard(writer)
            writer.close()
