"""When the gateway polls the wheel speeds, and how fast it really did, sans I/O.

Polls follow a grid of ``1 / poll_hz`` from the clock's zero, so every robot of a process polls at the same
instants and a fleet wakes once per period; behind, the next grid instant is taken, without a burst.
"""

from __future__ import annotations

import math
from collections import deque

#: The measured poll rate is taken over this window of readings (s).
RATE_WINDOW_S = 2.0


class PollSchedule:
    def __init__(self, poll_hz: float) -> None:
        self.period = 1.0 / poll_hz
        self._next = math.inf
        self._starting = False
        self._readings: deque[float] = deque(maxlen=4096)

    def start(self, now: float) -> None:
        """The control link is up: the first poll is due at once, the next on the grid at least half a period later."""
        self._next, self._starting = now, True

    def stop(self) -> None:
        self._next = math.inf

    def due(self, now: float) -> bool:
        """Whether a poll is due at ``now``; if so, the grid moves on (the caller polls or counts a skip)."""
        if now < self._next:
            return False
        period = self.period
        # after the link-up's poll, half a period at least (one a hair later would only wait for that reading)
        after = now + 0.5 * period if self._starting else now
        self._starting = False
        # within a millionth of a period is on the grid (4.1 / 0.02 = 204.99999999999997), or it comes due again an ulp later
        following = (math.floor(after / period + 1e-6) + 1.0) * period
        self._next = following if following > now else following + period
        return True

    def next_deadline(self) -> float:
        return self._next

    def reading(self, now: float) -> None:
        self._readings.append(now)

    def rate(self, now: float) -> float:
        """Readings per second over the last RATE_WINDOW_S (0 with fewer than two); older ones are forgotten here."""
        readings = self._readings
        while readings and now - readings[0] > RATE_WINDOW_S:
            readings.popleft()
        if len(readings) < 2:
            return 0.0
        return (len(readings) - 1) / max(readings[-1] - readings[0], 1e-9)
