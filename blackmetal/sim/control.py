"""One control client of the simulated robot: requests in, replies out, with the link's faults.

Driven by an asyncio protocol for TCP (docs/performance.md) or a coroutine reading a memory pipe.
Replies leave in the order of their requests, whatever the faults hold back or delay.
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from blackmetal import wire
from blackmetal.wire import Malformed

from .physics import SimRobot

log = logging.getLogger("blackmetal.sim")

#: How long a reply held back to be glued to the next one may wait (s).
GLUE_HOLD_S = 0.05
#: How long the second part of a split reply follows the first (s).
SPLIT_GAP_S = 0.002
#: A timer is set this much after the reply's time: uvloop rounds timers to whole milliseconds and may wake a little
#: early, and a wake before the time would only set the timer again, at once, until the clock caught up.
TIMER_SLACK_S = 0.001


class ReplySink(Protocol):
    def write(self, data: bytes) -> None: ...

    def close(self) -> None: ...

    def is_closing(self) -> bool: ...


@dataclass(eq=False)
class ControlSession:
    """Feeds one client's bytes to the robot and writes its replies to ``sink``, faults applied."""

    robot: SimRobot
    sink: ReplySink
    clock: Callable[[], float]
    _loop: asyncio.AbstractEventLoop
    _on_malformed: Callable[[], None]
    _decoder: wire.RequestDecoder = field(default_factory=wire.RequestDecoder, init=False)
    #: Replies waiting for their time (loop time), in the order of their requests; written by :meth:`_write_due`.
    _later: deque[tuple[float, bytes]] = field(default_factory=deque, init=False)
    _later_timer: asyncio.TimerHandle | None = field(default=None, init=False)
    #: Replies held back to be glued to the next ones, or written after GLUE_HOLD_S.
    _held: bytearray = field(default_factory=bytearray, init=False)
    _held_timer: asyncio.TimerHandle | None = field(default=None, init=False)

    def feed(self, data: bytes) -> None:
        """Bytes from the client: every whole request handled, its replies written or scheduled."""
        robot = self.robot
        for item in self._decoder.feed(data):
            if self.sink.is_closing():
                return  # a dropped client's requests, read before the drop, never reach the robot
            if isinstance(item, Malformed):
                self._on_malformed()
                log.warning("ignoring malformed request: %s", item.reason)
                continue
            faults = robot.faults
            if faults.disconnect and robot.rng.random() < faults.disconnect:
                log.info("fault: dropping the control connection")
                self.close()
                return
            replies = robot.handle(item, self.clock())
            if not faults.silent:
                self._reply(b"".join(replies))

    def close(self) -> None:
        """Close the connection; replies still held or delayed are dropped with it, as a reset link drops them."""
        for timer in (self._later_timer, self._held_timer):
            if timer is not None:
                timer.cancel()
        self._later_timer = self._held_timer = None
        self._later.clear()
        self._held.clear()
        self.sink.close()

    def _reply(self, data: bytes) -> None:
        faults = self.robot.faults
        if not (faults.garbage or faults.glue or faults.split or faults.delay or self._held or self._later):
            self.sink.write(data)  # the usual case: no fault, nothing waiting before it
            return
        rng = self.robot.rng
        if faults.garbage and rng.random() < faults.garbage:
            data = rng.randbytes(rng.randint(1, 24)) + data
        if faults.glue and rng.random() < faults.glue:
            self._held += data  # sent together with the next replies
            if self._held_timer is None:
                self._held_timer = self._loop.call_later(GLUE_HOLD_S, self._release_held)
            return
        if self._held:
            data = bytes(self._held) + data
            self._held.clear()
        at = self._loop.time() + faults.delay
        if faults.split and len(data) > 1 and rng.random() < faults.split:
            cut = rng.randint(1, len(data) - 1)
            self._write_at(at, data[:cut])
            self._write_at(at + SPLIT_GAP_S, data[cut:])
        else:
            self._write_at(at, data)

    def _release_held(self) -> None:
        self._held_timer = None
        if self._held:
            data = bytes(self._held)
            self._held.clear()
            self._write_at(self._loop.time(), data)

    def _write_at(self, at: float, data: bytes) -> None:
        """Write ``data`` at loop time ``at``, and never before a reply scheduled earlier."""
        if not self._later and at <= self._loop.time():
            self.sink.write(data)
            return
        self._later.append((at, data))
        if self._later_timer is None:
            self._later_timer = self._loop.call_at(self._later[0][0] + TIMER_SLACK_S, self._write_due)

    def _write_due(self) -> None:
        self._later_timer = None
        now = self._loop.time()
        later = self._later
        while later and later[0][0] <= now:
            data = later.popleft()[1]
            if not self.sink.is_closing():
                self.sink.write(data)
        if later:
            self._later_timer = self._loop.call_at(later[0][0] + TIMER_SLACK_S, self._write_due)
