"""Pairing the robot's replies with our requests, sans I/O.

The robot answers in order: a status for each request, then data for the GET commands (unless FULL_BUFFER).
Replies are matched by kind, so a garbled or lost reply costs one request, not the alignment of all that follow.
A request unanswered for ``reply_timeout`` is reported lost but keeps its place for ``late_horizon`` to take a
late reply; while one is in doubt the core sends nothing but stops, so a reply is never paired with a later request.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from blackmetal.wire import DATA_COMMANDS, CommandCode, Malformed, PositionReading, Reply, Request, SpeedReading, StatusReply

_DATA_KIND = {CommandCode.GET_LR_WHEEL_VELOCITY: SpeedReading, CommandCode.GET_LR_WHEEL_POSITION: PositionReading}


@dataclass(slots=True)
class Pending:
    request: Request
    sent_at: float
    status: StatusReply | None = None
    status_at: float | None = None
    expired: bool = False  # reported lost; kept to take its late reply


@dataclass(frozen=True, slots=True)
class Completed:
    request: Request
    status: StatusReply
    data: SpeedReading | PositionReading | None
    rtt: float  # seconds from sending to the status reply
    late: bool = False  # it came after the request had been reported lost


@dataclass(frozen=True, slots=True)
class Lost:
    """A request whose (data) reply never came or could not be read."""

    request: Request
    reason: str


@dataclass(slots=True)
class Exchange:
    reply_timeout: float = 0.5
    #: How long a request reported lost still waits for a late reply (s).
    late_horizon: float = 1.5
    outstanding: deque[Pending] = field(default_factory=deque)

    def sent(self, request: Request, now: float) -> None:
        self.outstanding.append(Pending(request, now))

    @property
    def in_doubt(self) -> bool:
        """A request past its reply timeout is still waiting: a reply now may be late, or the next one's (the head
        alone tells: requests expire in sending order)."""
        outstanding = self.outstanding
        return bool(outstanding) and outstanding[0].expired

    def polls_in_flight(self) -> int:
        return sum(1 for p in self.outstanding if p.request.command is CommandCode.GET_LR_WHEEL_VELOCITY)

    def received(self, item: Reply | Malformed, now: float) -> list[Completed | Lost]:
        out: list[Completed | Lost] = []
        if isinstance(item, StatusReply):
            # a status while the head waits for data: that data reply was lost
            while self.outstanding and self.outstanding[0].status is not None:
                out.append(Lost(self.outstanding.popleft().request, "data reply missing"))
            if not self.outstanding:
                return out  # a status nobody asked for: nothing to pair it with
            head = self.outstanding[0]
            head.status, head.status_at = item, now
            if not (item.ok and head.request.command in DATA_COMMANDS):
                self.outstanding.popleft()
                out.append(Completed(head.request, item, None, now - head.sent_at, head.expired))
        elif isinstance(item, (SpeedReading, PositionReading)):
            waiting = self.outstanding[0] if self.outstanding else None
            if waiting is None or waiting.status is None or _DATA_KIND.get(waiting.request.command) is not type(item):
                return out  # data nobody waits for: ignored, the pairing stays exact
            self.outstanding.popleft()
            assert waiting.status_at is not None
            out.append(Completed(waiting.request, waiting.status, item, waiting.status_at - waiting.sent_at, waiting.expired))
        return out  # a log report or garbage on the control port pairs with nothing

    def expire(self, now: float) -> list[Lost]:
        """Requests past their reply timeout, reported once each; those past the late horizon are forgotten."""
        lost: list[Lost] = []
        for pending in self.outstanding:
            if now < pending.sent_at + self.reply_timeout:
                break  # in sending order: the rest are younger
            if not pending.expired:
                pending.expired = True
                lost.append(Lost(pending.request, f"no reply within {self.reply_timeout:.3g} s"))
        while self.outstanding and now >= self.outstanding[0].sent_at + self.late_horizon:
            self.outstanding.popleft()
        return lost

    def next_expiry(self) -> float:
        """When :meth:`expire` next has something to do (inf if nothing is outstanding)."""
        if not self.outstanding:
            return float("inf")
        deadline = self.outstanding[0].sent_at + self.late_horizon
        for pending in self.outstanding:
            if not pending.expired:
                return min(deadline, pending.sent_at + self.reply_timeout)
        return deadline

    def forget_expired(self) -> int:
        """Give up every request in doubt for good (before a stop must go out): how many were dropped."""
        kept = deque(p for p in self.outstanding if not p.expired)
        dropped = len(self.outstanding) - len(kept)
        self.outstanding = kept
        return dropped

    def clear(self, reason: str) -> list[Lost]:
        lost = [Lost(p.request, reason) for p in self.outstanding]
        self.outstanding.clear()
        return lost
