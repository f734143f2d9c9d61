"""PREPARE_WHEEL_CONTROLLER after every connect, re-sent as any command the robot did not take (a pure part)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from .safety import retry_delay


@dataclass
class PrepareRetry:
    attempts: int = 0
    _at: float | None = None

    def reset(self) -> None:
        """A new connection: a fresh PREPARE goes out, with no retries behind it."""
        self.attempts, self._at = 0, None

    def cancel(self) -> None:
        self._at = None

    def taken(self) -> None:
        self.attempts = 0

    def dropped(self, now: float) -> None:
        """The robot did not take it: plan a re-send (unless one is planned)."""
        if self._at is None:
            self.attempts += 1
            self._at = now + retry_delay(self.attempts)

    def due(self, now: float) -> bool:
        """Whether to send it again now (once per planned re-send)."""
        if self._at is None or now < self._at:
            return False
        self._at = None
        return True

    def next_deadline(self) -> float:
        return math.inf if self._at is None else self._at
