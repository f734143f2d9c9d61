"""Byte streams to and from the robot: TCP, or an in-memory pipe, selected like any other transport.

A :class:`ByteStream` reads, writes and closes; a :class:`Connector` opens
the robot's control or log stream. The gateway takes a Connector, and the
simulator serves ByteStreams, so tests swap TCP for :func:`memory_pipe` the
way httpx swaps its transport, with nothing patched.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import socket
from collections.abc import Callable, Coroutine
from typing import Any, Protocol, cast

#: send() flags for a write that must never block (and never raise SIGPIPE), where the platform has them.
_SEND_NOW_FLAGS = getattr(socket, "MSG_DONTWAIT", 0) | getattr(socket, "MSG_NOSIGNAL", 0)


class ByteStream(Protocol):
    """One side of a duplex byte stream."""

    async def pump(self, deliver: Callable[[bytes], None]) -> None:
        """Hand each chunk read to ``deliver``, on the loop, as it comes; return once the peer has closed.

        Raises ConnectionError if the stream broke, and what ``deliver`` raised (the stream is closed then). Pushed,
        not read: no task wakes per chunk (a fleet gateway reads 5 000 replies a second).
        """
        ...

    def write(self, data: bytes) -> None:
        """Queue ``data`` for sending now (never blocks)."""
        ...

    def write_now(self, data: bytes) -> int:
        """Any thread, holding what keeps :meth:`write` and :meth:`close` out (the core lock): send ``data`` at once
        if nothing is queued before it; how many bytes went (0: none, always for a stream that cannot)."""
        ...

    async def drain(self) -> None:
        """Wait until written data has left (raises ConnectionError if the stream broke)."""
        ...

    def close(self) -> None: ...

    def is_closing(self) -> bool: ...


class Connector(Protocol):
    """Opens the robot's ``"control"`` or ``"log"`` stream."""

    async def open(self, port: str) -> ByteStream: ...

    def describe(self, port: str) -> str: ...


#: Most bytes handed over at once: a robot flooding its socket gets the loop's timers and inputs run between chunks,
#: so it cannot starve the e-stop, the brake or the polls (a loop reads up to 256 KiB in one go).
CHUNK = 4096
#: Bytes kept while nobody pumps yet; beyond them the socket is no longer read (the peer waits), as a stream reader's limit.
EARLY_LIMIT = 64 * 1024


def nodelay(transport: asyncio.BaseTransport) -> asyncio.Transport:
    """A new TCP connection's transport, with Nagle off: a command, a reply leaves at once, not with the next one."""
    sock = transport.get_extra_info("socket")
    if sock is not None:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return cast(asyncio.Transport, transport)  # uvloop's is no subclass of asyncio's, but is one


class _TcpProtocol(asyncio.Protocol):
    """The loop's side of one TCP connection: what it reads goes to the pump's ``deliver``, or waits for the pump."""

    def __init__(self) -> None:
        self.transport: asyncio.Transport | None = None
        self._deliver: Callable[[bytes], None] | None = None
        self._early = bytearray()  # read before anyone pumped
        #: The pump's end: None once the peer closed, the exception once the stream broke or ``deliver`` raised.
        self._ended: asyncio.Future[None] | None = None
        self._end: BaseException | None = None
        #: Nothing more is handed over: the stream ended, ``deliver`` raised, or the pump was cancelled.
        self._over = False
        self._paused = False
        self._drainers: list[asyncio.Future[None]] = []

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = nodelay(transport)

    def data_received(self, data: bytes) -> None:
        if self._over:
            return
        if self._deliver is None:
            self._early += data
            if len(self._early) > EARLY_LIMIT and self.transport is not None:
                self.transport.pause_reading()  # the pump's hand-over of these resumes it
            return
        self._hand_over(data)

    def _hand_over(self, data: bytes) -> None:
        if len(data) <= CHUNK:
            self._give(data)
            return
        # a flood: CHUNK bytes at a time, the loop's timers and inputs between them, no more read meanwhile
        assert self.transport is not None
        self.transport.pause_reading()
        self._give_from(memoryview(data), 0)

    def _give_from(self, data: memoryview, start: int) -> None:
        if self._deliver is None:
            return  # the stream ended meanwhile
        end = start + CHUNK
        self._give(bytes(data[start:end]))
        if end < len(data):
            asyncio.get_running_loop().call_soon(self._give_from, data, end)
        elif self.transport is not None and not self.transport.is_closing():
            self.transport.resume_reading()

    def _give(self, data: bytes) -> None:
        deliver = self._deliver
        if deliver is None:
            return
        try:
            deliver(data)
        except BaseException as exc:  # the pump raises it; nothing more is read
            self._finish(exc)
            if self.transport is not None:
                self.transport.close()

    def eof_received(self) -> bool:
        self._finish(None)
        return False  # close our side as well, as the robot's link is gone

    def connection_lost(self, exc: Exception | None) -> None:
        self._finish(ConnectionResetError(str(exc) or type(exc).__name__) if exc is not None else None)
        for waiter in self._drainers:
            if not waiter.done():
                waiter.set_exception(ConnectionResetError("connection lost"))
        self._drainers.clear()

    def pause_writing(self) -> None:
        self._paused = True

    def resume_writing(self) -> None:
        self._paused = False
        for waiter in self._drainers:
            if not waiter.done():
                waiter.set_result(None)
        self._drainers.clear()

    def _finish(self, end: BaseException | None) -> None:
        if self._over:
            return
        self._over, self._end, self._deliver = True, end, None
        if self._ended is not None and not self._ended.done():
            if end is None:
                self._ended.set_result(None)
            else:
                self._ended.set_exception(end)

    async def pump(self, deliver: Callable[[bytes], None]) -> None:
        if self._ended is not None:
            raise RuntimeError("a stream is pumped once")
        self._ended = asyncio.get_running_loop().create_future()
        early = bytes(self._early)
        self._early.clear()
        if self._over:  # the stream ended before anyone pumped: what came before its end, then how it ended
            try:
                for start in range(0, len(early), CHUNK):
                    deliver(early[start : start + CHUNK])
            except BaseException:
                if self.transport is not None:
                    self.transport.close()
                raise
            if self._end is not None:
                raise self._end
            return
        self._deliver = deliver
        if early:
            self._hand_over(early)  # chunked (resuming a read paused at EARLY_LIMIT), and what deliver raises ends the pump
        try:
            await self._ended
        finally:
            if not self._over:  # cancelled: nothing is handed to anyone from now on
                self._over, self._deliver = True, None

    async def drain(self) -> None:
        if self._over and self.transport is not None and self.transport.is_closing():
            raise ConnectionResetError("connection lost")
        if not self._paused:
            return
        waiter = asyncio.get_running_loop().create_future()
        self._drainers.append(waiter)
        await waiter


class TcpStream:
    """A ByteStream over an asyncio TCP connection (Nagle off: commands leave at once)."""

    def __init__(self, transport: asyncio.Transport, protocol: _TcpProtocol, *, write_now: bool = False) -> None:
        """``write_now``: keep a duplicate of the socket for :meth:`write_now`, made here on the loop while the
        descriptor is surely this stream's (a number the loop freed could name another socket later)."""
        self._transport = transport
        self._protocol = protocol
        sock = transport.get_extra_info("socket")
        self._own: socket.socket | None = None
        if write_now and sock is not None and hasattr(socket, "MSG_DONTWAIT"):
            self._own = socket.socket(fileno=os.dup(sock.fileno()))

    @classmethod
    async def connect(cls, host: str, port: int, *, write_now: bool = False) -> TcpStream:
        """Connect to ``host:port`` (raises OSError as the loop does)."""
        transport, protocol = await asyncio.get_running_loop().create_connection(_TcpProtocol, host, port)
        return cls(transport, protocol, write_now=write_now)

    async def pump(self, deliver: Callable[[bytes], None]) -> None:
        await self._protocol.pump(deliver)

    def write(self, data: bytes) -> None:
        self._transport.write(data)

    def write_now(self, data: bytes) -> int:
        transport = self._transport
        own = self._own
        if own is None or transport.is_closing() or transport.get_write_buffer_size():
            return 0  # queued bytes go first, and only the loop sends those
        try:
            return own.send(data, _SEND_NOW_FLAGS)
        except OSError:  # full (EAGAIN), or broken: the loop's write meets it and the link reports it
            return 0

    async def drain(self) -> None:
        await self._protocol.drain()

    def close(self) -> None:
        """Close the link now. Bytes the peer has not taken yet are dropped (a reset): a robot that stopped reading
        would otherwise hold the closing link, and the gateway's reconnect, until TCP gave up, minutes later."""
        if self._transport.get_write_buffer_size():
            self._transport.abort()
        else:
            self._transport.close()
        if self._own is not None:
            with contextlib.suppress(OSError):
                self._own.close()
            self._own = None

    def is_closing(self) -> bool:
        return self._transport.is_closing()


async def serve_tcp(host: str, port: int, serve: Callable[[TcpStream], Coroutine[Any, Any, None]]) -> asyncio.Server:
    """Listen on ``host:port``; each client is served by a task running ``serve(stream)`` (raises OSError as the loop does)."""
    loop = asyncio.get_running_loop()
    serving: set[asyncio.Task[None]] = set()

    class _Served(_TcpProtocol):
        def connection_made(self, transport: asyncio.BaseTransport) -> None:
            super().connection_made(transport)
            task = loop.create_task(serve(TcpStream(cast(asyncio.Transport, transport), self)))
            serving.add(task)
            task.add_done_callback(serving.discard)

    return await loop.create_server(_Served, host, port)


class TcpConnector:
    """The real robot (or the simulator) over TCP/IPv4."""

    def __init__(self, host: str, control_port: int, log_port: int, timeout: float = 1.0) -> None:
        self.host = host
        self.ports = {"control": control_port, "log": log_port}
        self.timeout = timeout

    async def open(self, port: str) -> ByteStream:
        """Connect, or raise OSError/TimeoutError whose text names the reason (never empty)."""
        try:
            stream = await asyncio.wait_for(TcpStream.connect(self.host, self.ports[port], write_now=True), self.timeout)
        except TimeoutError:
            raise TimeoutError(f"no answer within {self.timeout:g} s (is the robot on, and is {self.host} its address?)") from None
        except ConnectionRefusedError:
            raise ConnectionRefusedError(f"connection refused (nothing listens on port {self.ports[port]})") from None
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc) or type(exc).__name__) from None
        return stream

    def describe(self, port: str) -> str:
        return f"{self.host}:{self.ports[port]}"


class MemoryStream:
    """One end of an in-memory duplex pipe; closing either end closes both, as a TCP close does."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._readable = asyncio.Event()
        self._eof = False
        self._closed = False
        self.peer: MemoryStream | None = None

    def _deliver(self, data: bytes) -> None:
        self._buffer += data
        self._readable.set()

    def _end(self) -> None:
        self._eof = True
        self._readable.set()

    async def pump(self, deliver: Callable[[bytes], None]) -> None:
        while True:
            while not self._buffer and not self._eof:
                self._readable.clear()
                await self._readable.wait()
            if not self._buffer:
                return
            data = bytes(self._buffer)
            self._buffer.clear()
            try:
                deliver(data)
            except BaseException:
                self.close()
                raise
            await asyncio.sleep(0)  # the other side's turn, as a socket's round trip would give it

    def write(self, data: bytes) -> None:
        if not self._closed and self.peer is not None:
            self.peer._deliver(data)

    def write_now(self, data: bytes) -> int:
        return 0  # the peer's buffer belongs to the loop

    async def drain(self) -> None:
        if self._closed:
            raise ConnectionResetError("pipe closed")
        await asyncio.sleep(0)

    def close(self) -> None:
        for side in (self, self.peer):
            if side is not None and not side._closed:
                side._closed = True
                side._end()

    def is_closing(self) -> bool:
        return self._closed


def memory_pipe() -> tuple[MemoryStream, MemoryStream]:
    """Two connected ends: what one writes the other reads."""
    a, b = MemoryStream(), MemoryStream()
    a.peer, b.peer = b, a
    return a, b
