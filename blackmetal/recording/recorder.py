"""Records Zenoh keys into an MCAP recording on a thread of its own: the Zenoh callbacks only queue."""

from __future__ import annotations

import threading
import time
from collections import deque
from contextlib import suppress
from typing import TYPE_CHECKING, Any

from blackmetal.schemas import payload_bytes

from .writer import McapRecording

if TYPE_CHECKING:
    import zenoh

DRAIN_PERIOD_S = 0.02


class SessionRecorder:
    """Subscribes to ``keyexprs`` on ``session`` and writes every sample to ``recording`` until stopped."""

    def __init__(self, session: "zenoh.Session", keyexprs: list[str], recording: McapRecording, flush_period: float = 1.0) -> None:
        self.recording = recording
        self.flush_period = flush_period
        self.error: BaseException | None = None
        self._queue: deque[tuple[str, bytes, int]] = deque()
        self._notes: deque[tuple[str, dict[str, str]]] = deque()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mcap-writer", daemon=True)
        self._thread.start()
        self._subscribers: list[Any] = [session.declare_subscriber(k, self._on_sample) for k in keyexprs]

    def _on_sample(self, sample: "zenoh.Sample") -> None:
        arrival = time.time_ns()
        self._queue.append((str(sample.key_expr), payload_bytes(sample), arrival))

    def note(self, name: str, data: dict[str, str]) -> None:
        """An MCAP metadata record (e.g. where a run starts and ends), written by the writer thread."""
        self._notes.append((name, data))

    def _drain(self) -> None:
        queue, write = self._queue, self.recording.write
        while queue:
            key, payload, arrival = queue.popleft()
            write(key, payload, arrival)
        while self._notes:
            self.recording.metadata(*self._notes.popleft())

    def _run(self) -> None:
        next_flush = time.monotonic() + self.flush_period
        try:
            while not self._stop.wait(DRAIN_PERIOD_S):
                self._drain()
                if time.monotonic() >= next_flush:
                    self.recording.flush()
                    next_flush = time.monotonic() + self.flush_period
        except BaseException as exc:  # a full disk: reported by stop()
            self.error = exc

    def stop(self) -> None:
        """Undeclare, write what is queued, finish the file. Idempotent."""
        for subscriber in self._subscribers:
            with suppress(Exception):
                subscriber.undeclare()
        self._subscribers = []
        self._stop.set()
        self._thread.join()
        if self.error is None:
            self._drain()
        self.recording.close()
