"""An in-memory robot: a Connector that wires the gateway straight to a SimServer's own handlers, no sockets,
so the contract tests run the same suite over memory and over TCP.
"""

from __future__ import annotations

import asyncio

from blackmetal.transport import ByteStream, memory_pipe

from .server import SimServer


class MemoryConnector:
    def __init__(self, server: SimServer) -> None:
        self.server = server
        self._tasks: set[asyncio.Task[None]] = set()

    async def open(self, port: str) -> ByteStream:
        if self.server.closed:
            raise ConnectionRefusedError(f"simulated robot is not listening ({port})")
        ours, theirs = memory_pipe()
        handler = self.server.serve_control if port == "control" else self.server.serve_log
        task = asyncio.create_task(handler(theirs))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return ours

    def describe(self, port: str) -> str:
        return f"memory:{port}"
