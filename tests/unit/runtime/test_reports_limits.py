"""Error reports stay bounded whatever key names a client invents: per family, one overall budget, bounded tables."""

from __future__ import annotations

from blackmetal.runtime.reports import MAX_TRACKED, OTHER_KEYS, ErrorReporter, ReportLimiter
from blackmetal.schemas import ErrorReport


def flood(reporter: ErrorReporter, names: int, seconds: float, family: str | None) -> None:
    """``names`` distinct keys reported evenly over ``seconds`` of fake time, the reporter's timer run as a core runs it."""
    for i in range(names):
        now = seconds * i / names
        reporter.report(f"robot/lock/n{i}", "unknown lock", now=now, family=family)
        if now >= reporter.next_deadline():
            reporter.tick(now)
    end = seconds
    while reporter.next_deadline() < end + 30:
        end = max(end, reporter.next_deadline())
        reporter.tick(end)


def test_a_hundred_thousand_names_of_one_family_give_a_bounded_number_of_reports() -> None:
    published: list[ErrorReport] = []
    reporter = ErrorReporter("gateway", published.append)
    flood(reporter, 100_000, 10.0, family="robot/lock/*")
    assert len(published) <= 200
    assert len(reporter.limiter._families) == 1
    # nothing is lost silently: each report published, or counted in the next one's (or a summary's) ``suppressed``
    assert sum(r.suppressed + ("rate-limited" not in r.reason) for r in published) == 100_000


def test_without_a_family_the_tables_stay_bounded_and_so_do_the_reports() -> None:
    published: list[ErrorReport] = []
    reporter = ErrorReporter("gateway", published.append)
    flood(reporter, 100_000, 10.0, family=None)
    assert len(reporter.limiter._families) <= MAX_TRACKED
    assert len(published) <= 200
    assert any(r.key == OTHER_KEYS for r in published)


def test_the_overall_budget_is_shared_and_no_family_is_starved() -> None:
    limiter = ReportLimiter()
    admitted = {"a": 0, "b": 0}
    for step in range(1000):  # 10 s, two families each flooding at 50 reports a second
        now = step * 0.01
        for family in admitted:
            admitted[family] += limiter.admit(family, now)[0]
    assert admitted["a"] > 0 and admitted["b"] > 0
    assert sum(admitted.values()) <= limiter.overall_burst + limiter.overall_rate * 10 + 1


def test_one_key_keeps_its_burst_and_refill() -> None:
    limiter = ReportLimiter(rate=5.0, burst=10)
    assert sum(limiter.admit("k", 0.0)[0] for _ in range(100)) == 10
    ok, suppressed = limiter.admit("k", 0.2)  # one token back after 0.2 s
    assert ok and suppressed == 90
    assert not limiter.admit("k", 0.2)[0]
