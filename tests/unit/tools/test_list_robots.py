"""robots: the live gateways' prefixes in natural order, and the table and JSON of their rows."""

from __future__ import annotations

from types import SimpleNamespace

import zenoh

from blackmetal.schemas import GatewayHealth, LinkHealth, make_pose
from blackmetal.tools.list_robots import RobotRow, alive_robots, natural, table

from .fake_session import FakeSession


def test_prefixes_sort_naturally() -> None:
    assert sorted(["fleet/r10", "fleet/r2", "a", "fleet/r1"], key=natural) == ["a", "fleet/r1", "fleet/r2", "fleet/r10"]


def test_the_expected_robots_are_collected_from_their_tokens() -> None:
    session = FakeSession()
    session.tokens = [SimpleNamespace(kind=zenoh.SampleKind.PUT, key_expr=f"fleet/r{k}/alive/gateway") for k in (10, 2)]
    assert alive_robots(session, timeout=2.0, expect=2) == ["fleet/r2", "fleet/r10"]  # type: ignore[arg-type]


def test_the_table_says_where_a_service_did_not_answer() -> None:
    link = LinkHealth(state="connected")
    health = GatewayHealth(stamp=0.0, control=link, log=LinkHealth(state="down"), poll_hz=50.0, estop=True, active_source="teleop")
    rows = [RobotRow("fleet/r1", health, make_pose(0.0, 1.0, -0.5, 0.0)), RobotRow("fleet/r2", None, None)]
    header, first, second = table(rows).splitlines()
    assert header.split() == ["prefix", "link", "(control/log)", "poll", "x", "(m)", "y", "(m)", "yaw", "(°)", "e-stop", "drives"]
    assert first.split() == ["fleet/r1", "connected/down", "50", "Hz", "+1.000", "-0.500", "+0.0", "ENGAGED", "teleop"]
    assert second.split() == ["fleet/r2", "no", "health", "-", "-", "-", "-", "-", "-"]
    assert rows[1].as_json() == {"prefix": "fleet/r2", "link": None, "poll_hz": None, "pose": None, "estop": None,
                                 "active_source": None, "health": None}  # fmt: skip
    assert rows[0].as_json()["link"] == {"control": "connected", "log": "down"}
