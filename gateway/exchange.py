"""Pairing the robot's replies with our requests, sans I/O.

The robot answers requests in order: a status reply for each, then a data
reply for the GET commands (unless the status is FULL_BUFFER). Requests
may be pipelined, so a velocity command never waits for a poll's reply.
Replies are matched by kind, so a garbled or lost reply costs one request,
not the alignment of all that follow; a request unanswered for
``reply_timeout`` is given up as lost.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from blackmetal.wire import (
    DATA_COMMANDS,
    CommandCode,
    LogReport,
    Malformed,
    PositionReading,
    Reply,
    Request,
    SpeedReading,
    StatusReply,
)

_DATA_KIND = {CommandCode.GET_LR_WHEEL_VELOCITY: SpeedReading, CommandCode.GET_LR_WHEEL_POSITION: PositionReading}


@dataclass(slots=True)
class Pending:
    request: Request
    sent_at: float
    status: StatusReply | None = None
    status_at: float | None = None


@dataclass(frozen=True, slots=True)
class Completed:
    """A request and everything the robot answered to it."""

    request: Request
    status: StatusReply
    data: SpeedReading | PositionReading | None
    rtt: float  # seconds from sending to the status reply


@dataclass(frozen=True, slots=True)
class Lost:
    """A request whose (data) reply never came or could not be read."""

    request: Request
    reason: str


@dataclass(slots=True)
class Exchange:
    reply_timeout: float = 0.5
    outstanding: deque[Pending] = field(default_factory=deque)
    unexpected: int = 0

    def sent(self, request: Request, now: float) -> None:
        self.outstanding.append(Pending(request, now))

    def polls_in_flight(self) -> int:
        return sum(1 for p in self.outstanding if p.request.command is CommandCode.GET_LR_WHEEL_VELOCITY)

    def received(self, item: Reply | Malformed, now: float) -> list[Completed | Lost]:
        out: list[Completed | Lost] = []
        if isinstance(item, StatusReply):
            # a status while the head waits for data: that data reply was lost
            while self.outstanding and self.outstanding[0].status is not None:
                out.append(Lost(self.outstanding.popleft().request, "data reply missing"))
            if not self.outstanding:
                self.unexpected += 1
                return out
            head = self.outstanding[0]
            head.status, head.status_at = item, now
            if not (item.ok and head.request.command in DATA_COMMANDS):
                self.outstanding.popleft()
                out.append(Completed(head.request, item, None, now - head.sent_at))
        elif isinstance(item, (SpeedReading, PositionReading)):
            waiting = self.outstanding[0] if self.outstanding else None
            if waiting is None or waiting.status is None or _DATA_KIND.get(waiting.request.command) is not type(item):
                self.unexpected += 1
                return out
            self.outstanding.popleft()
            assert waiting.status_at is not None
            out.append(Completed(waiting.request, waiting.status, item, waiting.status_at - waiting.sent_at))
        elif isinstance(item, LogReport):
            self.unexpected += 1
        return out

    def expire(self, now: float) -> list[Lost]:
        lost: list[Lost] = []
        while self.outstanding and now >= self.outstanding[0].sent_at + self.reply_timeout:
            lost.append(Lost(self.outstanding.popleft().request, f"no reply within {self.reply_timeout:.3g} s"))
        return lost

    def clear(self, reason: str) -> list[Lost]:
        lost = [Lost(p.request, reason) for p in self.outstanding]
        self.outstanding.clear()
        return lost

    def next_expiry(self) -> float:
        """When the oldest outstanding request will be given up (inf if none)."""
        return self.outstanding[0].sent_at + self.reply_timeout if self.outstanding else float("inf")
