"""TCP links to the robot: connect, read, detect silence, reconnect with backoff.

Thin I/O: bytes in go to a callback, bytes out are written at once (no
queue, so nothing can pile up behind a slow robot). How to open a
connection is injected (:class:`Connector`), so tests can swap the TCP
socket for an in-memory pipe to the simulator, the way httpx swaps its
transport.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import time
from collections.abc import Callable
from typing import Protocol

log = logging.getLogger("blackmetal.gateway")

Streams = tuple[asyncio.StreamReader, asyncio.StreamWriter]

#: Reconnect backoff: first retry after this long, doubling up to the cap.
BACKOFF_FIRST_S = 0.05
BACKOFF_MAX_S = 2.0


class Connector(Protocol):
    """Opens the robot's control and log connections."""

    async def open(self, port: str) -> Streams:
        """``port`` is ``"control"`` or ``"log"``."""
        ...

    def describe(self, port: str) -> str: ...


class TcpConnector:
    """The real robot (or the simulator) over TCP/IPv4."""

    def __init__(self, host: str, control_port: int, log_port: int, timeout: float = 1.0) -> None:
        self.host = host
        self.ports = {"control": control_port, "log": log_port}
        self.timeout = timeout

    async def open(self, port: str) -> Streams:
        reader, writer = await asyncio.wait_for(asyncio.open_connection(self.host, self.ports[port]), self.timeout)
        sock = writer.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # commands go out now, not in 40 ms
        return reader, writer

    def describe(self, port: str) -> str:
        return f"{self.host}:{self.ports[port]}"


class Link:
    """One reconnecting connection. ``state`` is ``down``, ``connecting`` or ``connected``.

    ``silent(now)`` is asked every ``check_period``; when it says the robot
    went quiet the connection is dropped and re-opened.
    """

    def __init__(
        self,
        name: str,
        connector: Connector,
        on_connected: Callable[[], None],
        on_data: Callable[[bytes, float], None],
        on_disconnected: Callable[[str], None],
        silence_timeout: float,
        clock: Callable[[], float] = time.monotonic,
        wallclock: Callable[[], float] = time.time,
    ) -> None:
        self.name = name
        self.connector = connector
        self.on_connected = on_connected
        self.on_data = on_data
        self.on_disconnected = on_disconnected
        self.silence_timeout = silence_timeout
        self.clock = clock
        self.wallclock = wallclock
        self.state = "down"
        self.connected_since: float | None = None  # Unix time
        self.reconnects = 0
        self.connections = 0
        self.last_error = ""
        self._writer: asyncio.StreamWriter | None = None
        self._last_rx = 0.0
        self._waiting_since: float | None = None  # first request sent since the last bytes received

    @property
    def connected(self) -> bool:
        return self.state == "connected" and self._writer is not None and not self._writer.is_closing()

    def write(self, data: bytes) -> bool:
        """Send bytes now; False if the link is down."""
        if not self.connected:
            return False
        assert self._writer is not None
        self._writer.write(data)
        if self._waiting_since is None:
            self._waiting_since = self.clock()
        return True

    def silent(self, now: float, expect_push: bool) -> bool:
        """Requests unanswered (or, for a push link, no data) for longer than the silence timeout."""
        if expect_push:
            return now - self._last_rx > self.silence_timeout
        return self._waiting_since is not None and now - self._waiting_since > self.silence_timeout

    def drop(self, reason: str) -> None:
        """Close the connection; ``run`` reconnects."""
        if self._writer is not None and not self._writer.is_closing():
            log.warning("%s link: dropping connection: %s", self.name, reason)
            self.last_error = reason
            self._writer.close()

    async def drain(self, timeout: float) -> None:
        if self._writer is not None and not self._writer.is_closing():
            try:
                await asyncio.wait_for(self._writer.drain(), timeout)
            except (ConnectionError, TimeoutError, asyncio.TimeoutError):
                pass

    async def run(self, stop: asyncio.Event) -> None:
        """Connect, read until the link fails, reconnect with backoff; until ``stop`` is set."""
        backoff = BACKOFF_FIRST_S
        first = True
        while not stop.is_set():
            self.state = "connecting"
            try:
                reader, writer = await self.connector.open(self.name)
            except (OSError, TimeoutError, asyncio.TimeoutError) as exc:
                self.state = "down"
                self.last_error = f"cannot connect to {self.connector.describe(self.name)}: {exc or type(exc).__name__}"
                if first:
                    log.warning("%s link: %s; retrying", self.name, self.last_error)
                    first = False
                await _sleep_or_stop(stop, backoff)
                backoff = min(BACKOFF_MAX_S, backoff * 2)
                continue
            first = True
            backoff = BACKOFF_FIRST_S
            self.connections += 1
            if self.connections > 1:
                self.reconnects += 1
            self._writer = writer
            self._last_rx = self.clock()
            self._waiting_since = None
            self.state = "connected"
            self.connected_since = self.wallclock()
            log.info("%s link: connected to %s", self.name, self.connector.describe(self.name))
            reason = "closed by the robot"
            try:
                self.on_connected()
                reason = await self._read(reader, stop)
            except (ConnectionError, OSError) as exc:
                reason = f"connection error: {exc}"
            finally:
                self.state = "down"
                self.connected_since = None
                self._writer = None
                writer.close()
            if not stop.is_set():
                log.warning("%s link: %s; reconnecting", self.name, self.last_error or reason)
            self.on_disconnected(self.last_error or reason)
            self.last_error = ""
            if not stop.is_set():
                await _sleep_or_stop(stop, BACKOFF_FIRST_S)

    async def _read(self, reader: asyncio.StreamReader, stop: asyncio.Event) -> str:
        """Read until EOF; stopping closes the writer, which ends the read with EOF."""
        while not stop.is_set():
            data = await reader.read(65536)
            if not data:
                return "closed by the robot" if not stop.is_set() else "gateway stopping"
            self._last_rx = self.clock()
            self._waiting_since = None
            self.on_data(data, self.wallclock())
        return "gateway stopping"


async def _sleep_or_stop(stop: asyncio.Event, delay: float) -> None:
    try:
        await asyncio.wait_for(stop.wait(), delay)
    except (TimeoutError, asyncio.TimeoutError):
        pass
