"""The Foxglove view's host: the WebSocket server the app connects to and, with ``--mcap``, the MCAP file.

The view (:mod:`blackmetal.foxglove.core`) logs into channels of the
current Foxglove context; this host opens what those channels reach (the
server, then the file) and closes them in reverse order. The view has no
timers, so the host only waits for the stop.
"""

from __future__ import annotations

import asyncio
from typing import Any

from schemas import ConfigError

from .settings import FoxgloveSettings


def url(host: str, port: int) -> str:
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    return f"ws://{shown}:{port}"


def start_server(settings: FoxgloveSettings) -> Any:
    import foxglove

    try:
        return foxglove.start_server(name="blackmetal", host=settings.host, port=settings.port)
    except Exception as exc:  # the SDK raises its own error with the OS reason
        raise ConfigError(
            f"cannot serve Foxglove on {settings.host}:{settings.port} ({exc}); is another server on that port? try --port 0 or another port"
        ) from None


class FoxgloveHost:
    """The server (and the MCAP file) of one view; :meth:`close` stops them, the file first."""

    def __init__(self, settings: FoxgloveSettings) -> None:
        import foxglove

        self.server = start_server(settings)
        self.url = url(settings.host, self.server.port)
        self._writer: Any = None
        if settings.mcap:
            try:
                self._writer = foxglove.open_mcap(settings.mcap, allow_overwrite=True)
            except Exception as exc:
                self.server.stop()
                raise ConfigError(f"cannot write {settings.mcap}: {exc}") from None

    async def run(self, stop: asyncio.Event) -> None:
        """Serve until ``stop``: the view's handlers run on the loop as the edge hands payloads over."""
        await stop.wait()

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        self.server.stop()
