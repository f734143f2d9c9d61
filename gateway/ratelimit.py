"""Rate limiting of error reports, so a flood of bad input cannot flood ``<prefix>/errors``."""

from __future__ import annotations


class ReportLimiter:
    """Token bucket per key: at most ``rate`` reports per second after a burst of ``burst``.

    ``admit`` says whether to publish now and how many reports of that key
    were suppressed since the last one that was published. Clock injected.
    """

    def __init__(self, rate: float = 5.0, burst: int = 10) -> None:
        self.rate = rate
        self.burst = burst
        self._tokens: dict[str, float] = {}
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self.total_suppressed = 0

    def admit(self, key: str, now: float) -> tuple[bool, int]:
        tokens = self._tokens.get(key, float(self.burst))
        last = self._last.get(key, now)
        tokens = min(float(self.burst), tokens + (now - last) * self.rate)
        self._last[key] = now
        if tokens >= 1.0:
            self._tokens[key] = tokens - 1.0
            return True, self._suppressed.pop(key, 0)
        self._tokens[key] = tokens
        self._suppressed[key] = self._suppressed.get(key, 0) + 1
        self.total_suppressed += 1
        return False, 0

    def due_summaries(self, now: float) -> list[tuple[str, int]]:
        """Keys whose suppressed count can be announced now (a token is free), with the count."""
        due: list[tuple[str, int]] = []
        for key in list(self._suppressed):
            tokens = min(float(self.burst), self._tokens.get(key, 0.0) + (now - self._last.get(key, now)) * self.rate)
            self._last[key] = now
            if tokens >= 1.0:
                self._tokens[key] = tokens - 1.0
                due.append((key, self._suppressed.pop(key)))
            else:
                self._tokens[key] = tokens
        return due
