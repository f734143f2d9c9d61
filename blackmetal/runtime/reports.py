"""Error reports on ``<prefix>/errors``, rate-limited, so a flood of bad input cannot flood the key.

Limits per key family with one overall budget; the tables stay bounded whatever key names a client invents.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from blackmetal.schemas import ErrorReport

#: The family that reports fall into once the limiter tracks MAX_TRACKED families and none is idle.
OTHER_KEYS = "(other keys)"
#: Families the limiter keeps state for, at most: a client that picks new key names cannot grow it.
MAX_TRACKED = 64


@dataclass(slots=True)
class _Bucket:
    """A token bucket and the reports it held back since the last one it let through."""

    tokens: float
    last: float
    suppressed: int = 0

    def refill(self, now: float, rate: float, burst: float) -> None:
        self.tokens = min(burst, self.tokens + max(now - self.last, 0.0) * rate)
        self.last = max(self.last, now)  # a clock that steps back must not credit the same time twice

    def full_at(self, rate: float, burst: float) -> float:
        """When the bucket is full again if nothing takes from it."""
        missing = max(burst - self.tokens, 0.0)
        return self.last + missing / rate if rate > 0 else (self.last if not missing else math.inf)


@dataclass
class ReportLimiter:
    """Token buckets per key family (``rate`` a second after a burst of ``burst``) under one overall budget. Clock injected.

    The family is what the caller says (``robot/lock/*`` for every lock name), else the key itself. At most
    ``max_tracked`` families are kept: a new one first evicts a family that is idle again (full bucket, nothing held
    back), else it is counted under :data:`OTHER_KEYS` (whose slot is kept free), so no client can grow the tables by
    inventing names. The overall bucket bounds what all families publish together, summaries included.
    """

    rate: float = 5.0
    burst: int = 10
    overall_rate: float = 10.0
    overall_burst: int = 30
    max_tracked: int = MAX_TRACKED
    _families: dict[str, _Bucket] = field(default_factory=dict, init=False)
    _overall: _Bucket | None = field(default=None, init=False)
    #: No family can be idle before this: a flood of new names then costs no scan of the table per report.
    _evict_at: float = field(default=-math.inf, init=False)

    def _family(self, family: str, now: float) -> tuple[str, _Bucket]:
        bucket = self._families.get(family)
        if bucket is not None:
            return family, bucket
        if family != OTHER_KEYS and self._named() >= self.max_tracked - 1:  # the last slot is kept for OTHER_KEYS
            if now >= self._evict_at:
                self._evict_idle(now)
            if self._named() >= self.max_tracked - 1:
                return self._family(OTHER_KEYS, now)
        bucket = self._families[family] = _Bucket(float(self.burst), now)
        return family, bucket

    def _named(self) -> int:
        return len(self._families) - (OTHER_KEYS in self._families)

    def _evict_idle(self, now: float) -> None:
        self._evict_at = math.inf
        for name, bucket in list(self._families.items()):
            bucket.refill(now, self.rate, self.burst)
            if bucket.suppressed == 0 and bucket.tokens >= self.burst:
                del self._families[name]
            elif bucket.suppressed == 0:
                self._evict_at = min(self._evict_at, bucket.full_at(self.rate, self.burst))

    def _took(self, bucket: _Bucket) -> None:
        """A token was taken and the held-back count announced: the bucket can be idle once it refills."""
        bucket.tokens -= 1.0
        bucket.suppressed = 0
        self._evict_at = min(self._evict_at, bucket.full_at(self.rate, self.burst))

    def _take_overall(self, now: float) -> bool:
        overall = self._overall
        if overall is None:
            overall = self._overall = _Bucket(float(self.overall_burst), now)
        overall.refill(now, self.overall_rate, self.overall_burst)
        if overall.tokens >= 1.0:
            overall.tokens -= 1.0
            return True
        return False

    def admit(self, family: str, now: float) -> tuple[bool, int]:
        """Whether a report of ``family`` may be published now, and how many of that family were held back before it."""
        _, bucket = self._family(family, now)
        bucket.refill(now, self.rate, self.burst)
        if bucket.tokens >= 1.0 and self._take_overall(now):
            suppressed = bucket.suppressed
            self._took(bucket)
            return True, suppressed
        bucket.suppressed += 1
        return False, 0

    @property
    def pending(self) -> bool:
        """Some reports were suppressed and not yet summarised."""
        families = self._families
        return bool(families) and any(bucket.suppressed for bucket in families.values())

    def due_summaries(self, now: float) -> list[tuple[str, int]]:
        """Families whose held-back count can be announced now (a token of their own and of the overall budget), with the count.

        An announced family moves to the back of the table, so when the overall budget runs short the next round starts
        with the others.
        """
        due: list[tuple[str, int]] = []
        for family, bucket in list(self._families.items()):
            if not bucket.suppressed:
                continue
            bucket.refill(now, self.rate, self.burst)
            if bucket.tokens >= 1.0 and self._take_overall(now):
                due.append((family, bucket.suppressed))
                self._took(bucket)
                del self._families[family]
                self._families[family] = bucket
        return due


#: How often suppressed-report summaries go out, at most (s).
SUMMARY_PERIOD_S = 1.0
#: How many of its latest reports a reporter keeps for a `get` on its errors key (a view started later sees them).
RECENT_REPORTS = 20


@dataclass(eq=False)
class ErrorReporter:
    """Builds ErrorReports and hands the admitted ones to ``publish``; the one owner of suppressed-report summaries.

    Every core owns one reporter, passes its ``now`` to :meth:`report` and :meth:`tick`, and counts
    :meth:`next_deadline` among its own deadlines: so no host keeps a timer of its own for summaries, and no clock is
    read behind the core's back.
    """

    #: The service whose reports these are (``gateway``, ``odometry``...): each report's ``source`` unless another says it.
    service: str
    publish: Callable[[ErrorReport], None]
    wallclock: Callable[[], float] = time.time
    limiter: ReportLimiter = field(default_factory=ReportLimiter)
    summary_period: float = SUMMARY_PERIOD_S
    _next_summary: float = field(default=-math.inf, init=False)
    #: The latest reports published, oldest first: a ``get`` on the errors key answers with them.
    recent: deque[ErrorReport] = field(default_factory=lambda: deque(maxlen=RECENT_REPORTS), init=False)

    def report(self, key: str, reason: str, excerpt: str = "", by: str | None = None, *, now: float, family: str | None = None) -> None:
        """Report one rejected input or fault on ``key`` at monotonic ``now`` (published unless rate-limited).

        ``by``: who the fault is of, when not the service (``robot``); the report's ``source``. ``family`` (e.g.
        ``robot/lock/*``) is what the limit counts against; give it wherever a client picks the key's last chunk.
        Default: the key.
        """
        admitted, suppressed = self.limiter.admit(family or key, now)
        if admitted:
            self._publish(key, reason, suppressed, excerpt, by)
        elif self._next_summary == -math.inf:
            self._next_summary = now + self.summary_period

    def _publish(self, key: str, reason: str, suppressed: int, excerpt: str = "", by: str | None = None) -> None:
        report = ErrorReport(self.wallclock(), by or self.service, key, reason, excerpt, suppressed)
        self.recent.append(report)
        self.publish(report)

    def next_deadline(self) -> float:
        """When :meth:`tick` has a summary to consider (inf: nothing was suppressed)."""
        return self._next_summary if self.limiter.pending else math.inf

    def tick(self, now: float) -> None:
        """Publish how many reports were suppressed, for each key that has a token again (at most once a period)."""
        if now < self._next_summary or not self.limiter.pending:
            return
        self._next_summary = now + self.summary_period
        for key, suppressed in self.limiter.due_summaries(now):
            if key != OTHER_KEYS:
                self._publish(key, f"{suppressed} more reports on {key} were rate-limited", suppressed)
            else:
                self._publish(
                    key, f"{suppressed} more reports on other keys were rate-limited (too many distinct keys to count each)", suppressed
                )
        if not self.limiter.pending:
            self._next_summary = -math.inf
