"""watch: the screen from the latest values, who drives, and the recent errors oldest first."""

from __future__ import annotations

from blackmetal.schemas import ErrorReport, GatewayHealth, LinkHealth, SourceHealth, make_pose
from blackmetal.tools.watch import describe_sources, recent_errors, render

from .fake_session import FakeSession, reply


def _health(**kwargs: object) -> GatewayHealth:
    return GatewayHealth(stamp=0.0, control=LinkHealth(state="connecting", reason="cannot connect to 10.0.0.2:5000"),
                         log=LinkHealth(state="connected"), **kwargs)  # type: ignore[arg-type]  # fmt: skip


def test_nothing_known_yet_is_a_dash() -> None:
    assert render(None, None, None, None, [], 0.0) == ["pose    -   (0/s)", "status  -", "health  -", "errors  0 recent: none"]


def test_the_health_line_says_why_a_link_is_down_and_who_drives() -> None:
    sources = {"teleop": SourceHealth(priority=100, age=1.5, dropped=2), "nav": SourceHealth(priority=10, age=None)}
    health = _health(active_source="nav", sources=sources, locks={"bumper": True})
    lines = render(make_pose(0.0, 1.0, 2.0, 0.0), None, None, health, [], 50.0)
    assert lines[2].startswith("health  control connecting: cannot connect to 10.0.0.2:5000 (reconnects 0), log connected;")
    assert lines[3] == "drivers nav drives; teleop (100) 1.5 s ago, 2 dropped; locks: bumper ENGAGED"
    assert describe_sources(_health()) == "nobody drives"


def test_recent_errors_are_oldest_first() -> None:
    late, early = (ErrorReport(stamp=s, source="gateway", key="robot/cmd_vel", reason=r) for s, r in ((2.0, "late"), (1.0, "early")))
    session = FakeSession({"robot/errors": [reply(late), reply(early)]})
    assert [e.reason for e in recent_errors(session, "robot/errors", 1.0)] == ["early", "late"]  # type: ignore[arg-type]
