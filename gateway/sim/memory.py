"""An in-memory robot link: the gateway's Connector wired straight to a SimServer.

Like httpx's MockTransport: the gateway runs unchanged, selecting this
connector instead of TCP, and the simulator's own connection handlers serve
it, so the contract tests run the same suite over memory and over TCP.
"""

from __future__ import annotations

import asyncio
from typing import Any

from .server import SimServer


class _PipeWriter:
    """The writing half of an in-memory duplex pipe (the subset of StreamWriter we use)."""

    def __init__(self, peer: asyncio.StreamReader, own: asyncio.StreamReader) -> None:
        self._peer = peer
        self._own = own
        self._closed = False
        self.partner: _PipeWriter | None = None

    def write(self, data: bytes) -> None:
        if not self._closed:
            self._peer.feed_data(data)

    async def drain(self) -> None:
        if self._closed:
            raise ConnectionResetError("pipe closed")
        await asyncio.sleep(0)

    def is_closing(self) -> bool:
        return self._closed

    def close(self) -> None:
        """Close both directions, as a TCP close does."""
        for side in (self, self.partner):
            if side is not None and not side._closed:
                side._closed = True
                side._peer.feed_eof()

    async def wait_closed(self) -> None:
        return None

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        return default


def _pipe() -> tuple[asyncio.StreamReader, _PipeWriter, asyncio.StreamReader, _PipeWriter]:
    client_reader, server_reader = asyncio.StreamReader(), asyncio.StreamReader()
    client_writer = _PipeWriter(server_reader, client_reader)
    server_writer = _PipeWriter(client_reader, server_reader)
    client_writer.partner, server_writer.partner = server_writer, client_writer
    return client_reader, client_writer, server_reader, server_writer


class MemoryConnector:
    """Connects the gateway to ``server`` without sockets."""

    def __init__(self, server: SimServer) -> None:
        self.server = server
        self._tasks: set[asyncio.Task[None]] = set()

    async def open(self, port: str) -> tuple[asyncio.StreamReader, Any]:
        if self.server.closed:
            raise ConnectionRefusedError(f"simulated robot is not listening ({port})")
        client_reader, client_writer, server_reader, server_writer = _pipe()
        handler = self.server.serve_control if port == "control" else self.server.serve_log
        task = asyncio.create_task(handler(server_reader, server_writer))  # type: ignore[arg-type]
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return client_reader, client_writer

    def describe(self, port: str) -> str:
        return f"memory:{port}"
