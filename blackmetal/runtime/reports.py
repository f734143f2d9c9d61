"""Error reports on ``<prefix>/errors``, rate-limited, so a flood of bad input cannot flood the key.

Every service reports what it rejects through one :class:`ErrorReporter`:
a reason a person can act on, a short excerpt of the input, and how many
reports of the same key were suppressed since the last one published.
"""

from __future__ import annotations

import math
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

    @property
    def pending(self) -> bool:
        """Some reports were suppressed and not yet summarised."""
        return bool(self._suppressed)

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


#: How often suppressed-report summaries go out, at most (s).
SUMMARY_PERIOD_S = 1.0


class ErrorReporter:
    """Builds ErrorReports and hands the admitted ones to ``publish``; the one owner of suppressed-report summaries.

    Every core owns one reporter, passes its ``now`` to :meth:`report` and
    :meth:`tick`, and counts :meth:`next_deadline` among its own deadlines:
    so no host keeps a timer of its own for summaries, and no clock is read
    behind the core's back.
    """

    def __init__(
        self,
        source: str,
        publish: Callable[[ErrorReport], None],
        wallclock: Callable[[], float] = time.time,
        limiter: ReportLimiter | None = None,
        summary_period: float = SUMMARY_PERIOD_S,
    ) -> None:
        self.source = source
        self.publish = publish
        self.wallclock = wallclock
        self.limiter = limiter or ReportLimiter()
        self.summary_period = summary_period
        self._next_summary = -math.inf

    def report(self, key: str, reason: str, excerpt: str = "", source: str | None = None, *, now: float) -> None:
        """Report one rejected input or fault on ``key`` at monotonic ``now`` (published unless rate-limited)."""
        admitted, suppressed = self.limiter.admit(key, now)
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
        elif self._next_summary == -math.inf:
            self._next_summary = now + self.summary_period

    def next_deadline(self) -> float:
        """When :meth:`tick` has a summary to consider (inf: nothing was suppressed)."""
        return self._next_summary if self.limiter.pending else math.inf

    def tick(self, now: float) -> None:
        """Publish how many reports were suppressed, for each key that has a token again (at most once a period)."""
        if now < self._next_summary or not self.limiter.pending:
            return
        self._next_summary = now + self.summary_period
        for key, suppressed in self.limiter.due_summaries(now):
            self.publish(
                ErrorReport(
                    stamp=self.wallclock(),
                    source=self.source,
                    key=key,
                    reason=f"{suppressed} more reports on {key} were rate-limited",
                    suppressed=suppressed,
                )
            )
        if not self.limiter.pending:
            self._next_summary = -math.inf
