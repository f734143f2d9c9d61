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
from typing import Protocol

#: send() flags for a write that must never block (and never raise SIGPIPE), where the platform has them.
_SEND_NOW_FLAGS = getattr(socket, "MSG_DONTWAIT", 0) | getattr(socket, "MSG_NOSIGNAL", 0)


class ByteStream(Protocol):
    """One side of a duplex byte stream."""

    async def read(self, max_bytes: int) -> bytes:
        """Up to ``max_bytes`` bytes; ``b""`` once the peer has closed."""
        ...

    def write(self, data: bytes) -> None:
        """Queue ``data`` for sending now (never blocks)."""
        ...

    def write_now(self, data: bytes) -> int:
        """Any thread: send ``data`` at once if nothing is queued before it; how many bytes went (0: none).

        The caller sends the rest with :meth:`write`, on the loop. It must hold
        whatever keeps :meth:`write` and :meth:`close` from running meanwhile
        (the gateway's core lock). A stream that cannot send from another
        thread returns 0, always.
        """
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


class TcpStream:
    """A ByteStream over an asyncio TCP connection (Nagle off: commands leave at once)."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, *, write_now: bool = False) -> None:
        """``write_now``: keep a duplicate of the socket so :meth:`write_now` can send from another thread.

        It is made here, on the loop, while the descriptor is surely this
        stream's: the loop may close its own at any time (the robot reset the
        link), and a number it freed could name another socket by the time
        another thread looked. Only :meth:`close` closes the duplicate.
        """
        self._reader = reader
        self._writer = writer
        sock = writer.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._own: socket.socket | None = None
        if write_now and sock is not None and hasattr(socket, "MSG_DONTWAIT"):
            self._own = socket.socket(fileno=os.dup(sock.fileno()))

    async def read(self, max_bytes: int) -> bytes:
        return await self._reader.read(max_bytes)

    def write(self, data: bytes) -> None:
        self._writer.write(data)

    def write_now(self, data: bytes) -> int:
        transport = self._writer.transport
        own = self._own
        if own is None or transport.is_closing() or transport.get_write_buffer_size():
            return 0  # queued bytes go first, and only the loop sends those
        try:
            return own.send(data, _SEND_NOW_FLAGS)
        except OSError:  # full (EAGAIN), or broken: the loop's write meets it and the link reports it
            return 0

    async def drain(self) -> None:
        await self._writer.drain()

    def close(self) -> None:
        self._writer.close()
        if self._own is not None:
            with contextlib.suppress(OSError):
                self._own.close()
            self._own = None

    def is_closing(self) -> bool:
        return self._writer.is_closing()


class TcpConnector:
    """The real robot (or the simulator) over TCP/IPv4."""

    def __init__(self, host: str, control_port: int, log_port: int, timeout: float = 1.0) -> None:
        self.host = host
        self.ports = {"control": control_port, "log": log_port}
        self.timeout = timeout

    async def open(self, port: str) -> ByteStream:
        """Connect, or raise OSError/TimeoutError whose text names the reason (never empty)."""
        try:
            reader, writer = await asyncio.wait_for(asyncio.open_connection(self.host, self.ports[port]), self.timeout)
        except TimeoutError:
            raise TimeoutError(f"no answer within {self.timeout:g} s (is the robot on, and is {self.host} its address?)") from None
        except ConnectionRefusedError:
            raise ConnectionRefusedError(f"connection refused (nothing listens on port {self.ports[port]})") from None
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc) or type(exc).__name__) from None
        return TcpStream(reader, writer, write_now=True)

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

    async def read(self, max_bytes: int) -> bytes:
        while not self._buffer and not self._eof:
            self._readable.clear()
            await self._readable.wait()
        data = bytes(self._buffer[:max_bytes])
        del self._buffer[:max_bytes]
        return data

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
