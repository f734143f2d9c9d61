"""watch: the screen from the latest values, who drives, and the recent errors oldest first."""

from __future__ import annotations

import math

from blackmetal.schemas import ErrorReport, GatewayHealth, LinkHealth, SourceHealth, make_pose
from blackmetal.tools.watch import describe_goal, describe_sources, recent_errors, render

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


def test_the_navigations_goal_is_one_line_running_or_ended() -> None:
    from blackmetal.schemas import GoalState, NavFeedback, PlanarPose

    pose, goal = PlanarPose(0.1, 0.2, 0.0), PlanarPose(0.5, 0.3, math.pi / 2)
    running = NavFeedback(stamp=0.0, goal_id="5f0c" * 8, state=GoalState.EXECUTING, pose=pose, goal=goal, distance_remaining=0.34,
                          eta=1.9, elapsed=1.1)  # fmt: skip
    lines = render(None, None, None, None, [], 0.0, running)
    assert lines[-2] == "nav     goal 5f0c5f0c to (0.500, 0.300, 90.0°) in map executing: 0.340 m left, eta 1.9 s, 1.1 s so far"
    aborted = NavFeedback(stamp=0.0, goal_id="5f0c" * 8, state=GoalState.ABORTED, pose=pose, goal=goal, distance_remaining=0.3,
                          eta=0.0, elapsed=2.0, reason="e-stop engaged")  # fmt: skip
    assert describe_goal(aborted) == "goal 5f0c5f0c to (0.500, 0.300, 90.0°) in map aborted after 2.0 s: e-stop engaged"
