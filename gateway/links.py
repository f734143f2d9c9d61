"""The robot's two TCP links as the core sees them: state, silence timers (a pure part) and the host's reconnect pacing."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Literal

from blackmetal.schemas import LinkHealth

LinkName = Literal["control", "log"]
LINKS: tuple[LinkName, LinkName] = ("control", "log")


class LinkStatus(StrEnum):
    """Where a link stands; the value is what health reports carry."""

    DOWN = "down"
    CONNECTING = "connecting"
    CONNECTED = "connected"


@dataclass(frozen=True, slots=True)
class DropLink:
    """The host must close this link (it reconnects by itself)."""

    link: LinkName
    reason: str


@dataclass
class LinkState:
    status: LinkStatus = LinkStatus.DOWN
    #: ``status is CONNECTED``, kept with it by :class:`Links`: the core asks several times per poll.
    connected: bool = False
    connected_since: float | None = None  # Unix time, for health
    connections: int = 0
    last_rx: float = 0.0
    #: The first request sent since the last bytes received (None: nothing awaited).
    waiting_since: float | None = None
    #: When a link that was up went down (None: up, or never up).
    down_since: float | None = None
    #: Why it is not up: the last failure to open it or the reason it closed (None while up).
    reason: str | None = None

    @property
    def reconnects(self) -> int:
        return max(0, self.connections - 1)

    def health(self) -> LinkHealth:
        return LinkHealth(self.status.value, self.connected_since, self.reconnects, None if self.connected else self.reason)


@dataclass
class Links:
    """Both links' states and the silence rules that drop them (requests unanswered, or no state report, this long)."""

    silence_timeout: float
    log_silence_timeout: float
    control: LinkState = field(default_factory=LinkState)
    log: LinkState = field(default_factory=LinkState)

    def __getitem__(self, name: LinkName) -> LinkState:
        return self.control if name == "control" else self.log

    def connecting(self, name: LinkName) -> None:
        state = self[name]
        state.status, state.connected = LinkStatus.CONNECTING, False

    def up(self, name: LinkName, now: float, wall: float) -> float | None:
        """``name`` connected at ``now``: how long it had been down, if it was up before (for the report)."""
        state = self[name]
        state.status, state.connected, state.connected_since = LinkStatus.CONNECTED, True, wall
        state.connections += 1
        state.last_rx, state.waiting_since, state.reason = now, None, None
        down_for = None if state.down_since is None else now - state.down_since
        state.down_since = None
        return down_for

    def down(self, name: LinkName, now: float, reason: str) -> bool:
        """``name`` closed or could not be opened, for ``reason``: whether it had been up."""
        state = self[name]
        state.reason = reason
        was_up = state.connected
        state.status, state.connected, state.connected_since = LinkStatus.DOWN, False, None
        state.waiting_since = None
        if was_up:
            state.down_since = now
        return was_up

    def received(self, name: LinkName, now: float) -> None:
        state = self[name]
        state.last_rx, state.waiting_since = now, None

    def request_sent(self, now: float) -> None:
        """A request went out on the control link: its silence clock runs from the first unanswered one."""
        if self.control.waiting_since is None:
            self.control.waiting_since = now

    def due(self, now: float) -> list[DropLink]:
        """Links to drop at ``now`` because the robot went silent on them."""
        drops: list[DropLink] = []
        control, log = self.control, self.log
        if control.connected and control.waiting_since is not None and now >= control.waiting_since + self.silence_timeout:
            drops.append(DropLink("control", f"robot silent: no reply for {self.silence_timeout:.3g} s"))
            control.waiting_since = None
        if log.connected and now >= log.last_rx + self.log_silence_timeout:
            drops.append(DropLink("log", f"no state report for {self.log_silence_timeout:.3g} s"))
            log.last_rx = now
        return drops

    def next_deadline(self) -> float:
        """When :meth:`due` may next drop a link (inf: no silence clock runs)."""
        deadline = math.inf
        control, log = self.control, self.log
        if control.connected and control.waiting_since is not None:
            deadline = control.waiting_since + self.silence_timeout
        if log.connected:
            deadline = min(deadline, log.last_rx + self.log_silence_timeout)
        return deadline


@dataclass
class ReconnectBackoff:
    """How long to wait before the next connection attempt: doubling, capped, reset only by a connection that lasted
    ``stable`` seconds (a robot that accepts and at once closes gets attempts at the capped pace, not a storm)."""

    first: float = 0.05
    cap: float = 2.0
    stable: float = 5.0
    delay: float = field(init=False)
    _opened_at: float | None = None

    def __post_init__(self) -> None:
        self.delay = self.first

    def opened(self, now: float) -> None:
        self._opened_at = now

    def failed(self, now: float) -> float:
        """A connection attempt failed, or a connection ended: the pause before the next attempt."""
        if self._opened_at is not None and now - self._opened_at >= self.stable:
            self.delay = self.first
        wait = self.delay
        self.delay = min(self.cap, self.delay * 2)
        self._opened_at = None
        return wait
