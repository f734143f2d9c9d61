"""Error reports on ``<prefix>/errors``, rate-limited, so a flood of bad input cannot flood the key.

Every service reports what it rejects through one :class:`ErrorReporter`:
a reason a person can act on, a short excerpt of the input, and how many
reports of the same key were suppressed since the last one published.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from schemas import ErrorReport


class ReportLimiter:
    """Token bucket per key: at most ``rate`` reports per second after a burst of ``burst``. Clock injected.

    ``admit`` says whether to publish now and how many reports of that key
    were suppressed since the last one that was published.
    """

    def __init__(self, rate: float = 5.0, burst: int = 10) -> None:
        self.rate = rate
        self.burst = burst
        self._tokens: dict[str, float] = {}
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def _refill(self, key: str, now: float, default: float) -> float:
        tokens = min(float(self.burst), self._tokens.get(key, default) + (now - self._last.get(key, now)) * self.rate)
        self._last[key] = now
        return tokens

    def admit(self, key: str, now: float) -> tuple[bool, int]:
        tokens = self._refill(key, now, float(self.burst))
        if tokens >= 1.0:
            self._tokens[key] = tokens - 1.0
            return True, self._suppressed.pop(key, 0)
        self._tokens[key] = tokens
        self._suppressed[key] = self._suppressed.get(key, 0) + 1
        return False, 0

    def due_summaries(self, now: float) -> list[tuple[str, int]]:
        """Keys whose suppressed count can be announced now (a token is free), with the count."""
        due: list[tuple[str, int]] = []
        for key in list(self._suppressed):
            tokens = self._refill(key, now, 0.0)
            if tokens >= 1.0:
                self._tokens[key] = tokens - 1.0
                due.append((key, self._suppressed.pop(key)))
            else:
                self._tokens[key] = tokens
        return due


class ErrorReporter:
    """Builds ErrorReports and hands the admitted ones to ``publish``; call :meth:`flush` about once a second."""

    def __init__(
        self,
        source: str,
        publish: Callable[[ErrorReport], None],
        clock: Callable[[], float] = time.monotonic,
        wallclock: Callable[[], float] = time.time,
        limiter: ReportLimiter | None = None,
    ) -> None:
        self.source = source
        self.publish = publish
        self.clock = clock
        self.wallclock = wallclock
        self.limiter = limiter or ReportLimiter()
        self.reported = 0

    def report(self, key: str, reason: str, excerpt: str = "", source: str | None = None) -> None:
        """Report one rejected input or fault on ``key`` (published unless rate-limited)."""
        self.reported += 1
        admitted, suppressed = self.limiter.admit(key, self.clock())
        if admitted:
            self.publish(
                ErrorReport(
                    stamp=self.wallclock(),
                    source=source or self.source,
                    key=key,
                    reason=reason,
                    excerpt=excerpt,
                    suppressed=suppressed,
                )
            )

    def flush(self) -> None:
        """Publish how many reports were suppressed, for each key that has a token again."""
        for key, suppressed in self.limiter.due_summaries(self.clock()):
            self.publish(
                ErrorReport(
                    stamp=self.wallclock(),
                    source=self.source,
                    key=key,
                    reason=f"{suppressed} more reports on {key} were rate-limited",
                    suppressed=suppressed,
                )
            )
