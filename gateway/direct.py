"""A single robot's direct path: a command or an e-stop sent to the robot from the Zenoh thread that delivers it.

Waking the loop cost a command a third of its way to the robot, so a Zenoh
thread that finds the core free handles the input itself and sends the
bytes at once. This class owns everything that path needs, and nothing
else uses it:

* the core lock (:class:`~blackmetal.runtime.host.CoreLock`): the loop holds
  it whenever it is in the core; a Zenoh thread only tries it;
* the control stream the bytes go to, and the bytes it could not send;
* the send-now rule: bytes go at once only while the loop has nothing queued
  on the stream (:meth:`ByteStream.write_now`, on the stream's own duplicate
  of the socket); what cannot go now goes first in the loop's next write,
  before anything newer; the loop then publishes what the input produced.

Direct takes are allowed only while the host runs, and never on the loop's
own thread. The thread model is drawn in ``docs/threads.md``.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable

from blackmetal.runtime.host import CoreLock
from blackmetal.transport import ByteStream


class DirectPath:
    """See the module docstring. Every method is called holding :attr:`lock`."""

    def __init__(self) -> None:
        #: Held by whoever is in the core or writes to a robot stream: the loop, or a Zenoh thread taking an input directly.
        self.lock = CoreLock()
        self._stream: ByteStream | None = None
        #: Bytes a direct send could not write at once; the loop writes them before anything newer.
        self._unsent = b""
        #: The running loop and its thread; None while the host does not run (every input goes to the loop then).
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread = 0
        self._flush_scheduled = False

    # ------------------------------------------------------------------ the loop

    def open(self, loop: asyncio.AbstractEventLoop) -> None:
        """The host runs on ``loop``: other threads may take inputs directly from now on."""
        self._loop, self._loop_thread = loop, threading.get_ident()

    def shut(self) -> None:
        """The host stops or failed: from now on the loop takes every input."""
        self._loop = None

    def stream_up(self, stream: ByteStream) -> None:
        self._stream = stream

    def stream_down(self) -> None:
        """The control stream closed: nothing is written to it from now on, from any thread."""
        self._stream, self._unsent = None, b""

    def before(self, data: bytes) -> bytes:
        """What the control stream is to be sent, oldest first: a direct send's unsent rest, then ``data``."""
        rest, self._unsent = self._unsent, b""
        return rest + data if rest else data

    def flushed(self) -> None:
        """The flush that :meth:`send` scheduled has run."""
        self._flush_scheduled = False

    # ------------------------------------------------------------------ a Zenoh thread

    def allowed(self) -> bool:
        """Whether the calling thread may drive the core now (the host runs, and this is not its loop's thread)."""
        return self._loop is not None and threading.get_ident() != self._loop_thread

    def send(self, data: bytes, flush: Callable[[], None]) -> None:
        """``data`` (already :meth:`before`-ed) to the control stream as far as it takes it now; ``flush`` on the loop, once."""
        if data:
            stream = self._stream
            sent = stream.write_now(data) if stream is not None and not stream.is_closing() else 0
            if sent < len(data):
                self._unsent = data[sent:]
        if not self._flush_scheduled and self._loop is not None:
            self._flush_scheduled = True
            try:
                self._loop.call_soon_threadsafe(flush)
            except RuntimeError:  # the loop is closed: the host is gone
                pass
