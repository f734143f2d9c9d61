"""ErrorReporter and ReportLimiter under floods, on a fake clock: the cap holds at every step, not only at the end.

Complements tests/unit/runtime/test_reports_limits.py (per-family burst and refill, the
single-family account, two families sharing the overall budget).
"""

from __future__ import annotations

from collections import Counter

import pytest

from blackmetal.runtime.reports import MAX_TRACKED, OTHER_KEYS, ErrorReporter, ReportLimiter
from blackmetal.schemas import ErrorReport


def is_summary(report: ErrorReport) -> bool:
    return "rate-limited" in report.reason


def flood(reporter: ErrorReporter, published: list[ErrorReport], keys: list[str], seconds: float, family: str | None) -> tuple[int, int]:
    """Report ``keys`` evenly over ``seconds`` as a core would (ticking at its deadline), then drain the summaries.

    Returns the largest table the limiter ever held and how many reports were published within ``seconds``.
    """
    largest = 0
    for i, key in enumerate(keys):
        now = seconds * i / len(keys)
        reporter.report(key, "unknown", now=now, family=family)
        if now >= reporter.next_deadline():
            reporter.tick(now)
        largest = max(largest, len(reporter.limiter._families))
    within = len(published)
    end = seconds
    while reporter.next_deadline() < end + 60:
        end = max(end, reporter.next_deadline())
        reporter.tick(end)
        largest = max(largest, len(reporter.limiter._families))
    return largest, within


@pytest.mark.parametrize("family", ["robot/lock/*", None])
def test_a_hundred_thousand_names_never_grow_the_table_past_the_cap(family: str | None) -> None:
    published: list[ErrorReport] = []
    reporter = ErrorReporter("gateway", published.append)
    largest, within = flood(reporter, published, [f"robot/lock/n{i}" for i in range(100_000)], 10.0, family)
    assert largest <= (1 if family else MAX_TRACKED)
    assert within <= 150 and len(published) <= 200
    assert sum(r.suppressed + (not is_summary(r)) for r in published) == 100_000
    assert reporter.next_deadline() == float("inf")  # everything announced: no deadline left


def test_two_flooded_families_both_get_reports_and_each_account_adds_up() -> None:
    published: list[ErrorReport] = []
    reporter = ErrorReporter("gateway", published.append)
    keys = [f"robot/lock/n{i}" if i % 2 else f"robot/cmd_vel/n{i}" for i in range(40_000)]
    families = {"robot/lock/*": "robot/lock/", "robot/cmd_vel/*": "robot/cmd_vel/"}
    for i, key in enumerate(keys):
        now = 10.0 * i / len(keys)
        family = next(f for f, prefix in families.items() if key.startswith(prefix))
        reporter.report(key, "unknown", now=now, family=family)
        if now >= reporter.next_deadline():
            reporter.tick(now)
    end = 10.0
    while reporter.next_deadline() < end + 60:
        end = max(end, reporter.next_deadline())
        reporter.tick(end)
    reports = Counter(next(f for f, p in families.items() if r.key.startswith(p)) for r in published if not is_summary(r))
    assert reports["robot/lock/*"] > 0 and reports["robot/cmd_vel/*"] > 0
    for family, prefix in families.items():
        mine = [r for r in published if r.key.startswith(prefix) or r.key == family]
        assert sum(r.suppressed + (not is_summary(r)) for r in mine) == 20_000
    assert all(r.key in families for r in published if is_summary(r))  # summaries name the family, reports the real key
    assert len(reporter.limiter._families) == 2


def test_a_new_name_takes_an_idle_slot_else_falls_under_other_keys() -> None:
    limiter = ReportLimiter(max_tracked=4)
    for family in "abcabc":
        assert limiter.admit(family, 0.0) == (True, 0)  # three named slots, none idle before 0.4 s (two tokens short)
    for _ in range(20):
        limiter.admit("d", 0.0)  # no slot: counted under OTHER_KEYS, 10 held back
    assert len(limiter._families) == 4
    assert limiter.admit("e", 0.3) == (True, 10)  # still nothing idle: OTHER_KEYS again, with its held-back count
    assert limiter.admit("f", 1.0) == (True, 0)  # a, b, c are full again and evicted: f has a bucket of its own
    assert len(limiter._families) <= 4
    assert limiter.due_summaries(1.0) == []  # OTHER_KEYS' count went out on e's report


def test_summaries_take_turns_when_the_overall_budget_is_short() -> None:
    limiter = ReportLimiter(overall_rate=1.0, overall_burst=1)
    families = ["a", "b", "c", "d", "e"]
    announced: Counter[str] = Counter()
    for second in range(11):
        for family, _ in limiter.due_summaries(float(second)):
            announced[family] += 1
        for family in families:  # every family keeps flooding; the one overall token a second goes to summaries
            limiter.admit(family, float(second))
    assert set(announced) == set(families)


def test_a_clock_stepping_back_credits_no_tokens_twice() -> None:
    limiter = ReportLimiter(rate=5.0, burst=10, overall_burst=100)
    assert sum(limiter.admit("k", 0.0)[0] for _ in range(10)) == 10
    assert not limiter.admit("k", -5.0)[0]
    assert sum(limiter.admit("k", 0.2)[0] for _ in range(10)) == 1


def test_existing_calls_without_a_family_still_work() -> None:
    published: list[ErrorReport] = []
    reporter = ErrorReporter("gateway", published.append, wallclock=lambda: 42.0)
    reporter.report("robot/cmd_vel", "bad json", "{oops", "teleop", now=0.0)
    reporter.report("robot/lock/x", "unknown lock", now=0.0, family="robot/lock/*")
    assert [(r.key, r.source, r.excerpt, r.stamp) for r in published] == [
        ("robot/cmd_vel", "teleop", "{oops", 42.0),
        ("robot/lock/x", "gateway", "", 42.0),
    ]
    for _ in range(20):
        reporter.report("robot/lock/y", "unknown lock", now=0.0, family="robot/lock/*")
    assert reporter.next_deadline() == 1.0
    reporter.tick(1.0)
    assert published[-1].key == "robot/lock/*" and published[-1].reason == "11 more reports on robot/lock/* were rate-limited"
    assert published[-1].suppressed == 11 and reporter.next_deadline() == float("inf")


def test_other_keys_summary_says_other_keys() -> None:
    published: list[ErrorReport] = []
    reporter = ErrorReporter("gateway", published.append, limiter=ReportLimiter(max_tracked=2))
    for i in range(30):
        reporter.report(f"robot/lock/n{i}", "unknown lock", now=0.0)
    reporter.tick(1.0)
    (summary,) = [r for r in published if r.key == OTHER_KEYS]
    assert summary.reason.startswith(f"{summary.suppressed} more reports on other keys were rate-limited")
