"""The fleet's summary and log: each robot's row, lost and back (pure, on a fake clock)."""

from __future__ import annotations

import json
import math
from typing import Any

from blackmetal.foxglove.channels import Kind
from blackmetal.foxglove.fleet_view import FLEET_SUMMARY_SCHEMA, FleetSummary, FleetView
from blackmetal.foxglove.naming import FLEET_NAMESPACE
from blackmetal.schemas import ErrorReport, GatewayHealth, Keys, LinkHealth, Pose, encode

IDS = ("r1", "r2", "r3")


def _health(stamp: float, estop: bool = False, source: str | None = None, state: str = "connected") -> GatewayHealth:
    return GatewayHealth(
        stamp=stamp, control=LinkHealth(state), log=LinkHealth("connected"), estop=estop, active_source=source, poll_hz=50.0
    )


def test_the_summary_shows_each_robots_link_poll_rate_estop_and_driver() -> None:
    summary = FleetSummary([(rid, f"fleet/{rid}") for rid in IDS])
    summary.on_health("r1", _health(10.0, estop=True), now=100.0)
    summary.on_health("r2", _health(10.5, source="foxglove", state="connecting"), now=100.5)
    summary.on_pose("r2", Pose(stamp=10.5, x=1.0, y=2.0, yaw=0.5))
    message = summary.message(now=101.0)
    rows = {row["id"]: row for row in message["robots"]}
    assert [row["id"] for row in message["robots"]] == list(IDS)
    assert rows["r1"]["link"] == "connected/connected" and rows["r1"]["estop"] is True and rows["r1"]["poll_hz"] == 50.0
    assert rows["r1"]["health_age"] == 1.0
    assert rows["r2"]["link"] == "connecting/connected" and (rows["r2"]["x"], rows["r2"]["y"]) == (1.0, 2.0)
    assert rows["r3"]["link"] == "no health" and rows["r3"]["estop"] is None and rows["r3"]["poll_hz"] == 0.0
    assert message["robots_up"] == 1 and message["estop"] == ["r1"] and message["driving"] == {"r2": "foxglove"} and message["lost"] == []
    json.dumps(summary.message(now=101.0))  # what the channel carries


def test_a_robot_is_lost_when_its_health_stops_or_its_token_goes_and_back_with_its_next_health() -> None:
    summary = FleetSummary([(rid, f"fleet/{rid}") for rid in IDS])
    for rid in IDS:
        summary.on_token(rid, True, now=0.0)
    now = 0.0
    while now < 5.0:  # every robot's health once a second; r2's host drops off after 2.0 s
        for rid in IDS:
            if rid != "r2" or now <= 2.0:
                assert summary.on_health(rid, _health(now), now=now) is None
        now += 1.0
        changes = []
        while summary.next_deadline() <= now:
            changes += summary.tick(summary.next_deadline())
        if changes:
            assert [(c.robot_id, c.lost) for c in changes] == [("r2", True)] and "no health for 2.5 s" in changes[0].reason
            lost_at = summary.next_deadline()
            break
    assert summary.rows["r2"].lost and now == 5.0, "lost 2.5 s after its last health (at 2.0), seen by the tick due at 4.5"
    message = summary.message(now)
    assert message["lost"] == ["r2"] and message["robots_up"] == 2 and "lost" in {r["id"]: r for r in message["robots"]}["r2"]["link"]
    assert lost_at > now, "r1 and r3 still on time"
    back = summary.on_health("r2", _health(now), now=now)
    assert back is not None and not back.lost and summary.message(now)["lost"] == []
    gone = summary.on_token("r3", False, now=5.1)
    assert gone is not None and gone.lost and "liveliness token gone" in gone.reason
    assert summary.on_token("r3", False, now=5.2) is None, "lost once"
    summary.suspend()  # nobody follows health any more: no robot is lost for that silence
    assert summary.next_deadline() == math.inf and summary.tick(100.0) == []
    assert summary.message(100.0)["lost"] == ["r3"], "a gone token stays lost"


class Logged:
    """A channel that keeps what is logged into it, always watched."""

    def __init__(self, topic: str, kind: Kind, schema: dict[str, Any] | None, logs: dict[str, list[Any]]) -> None:
        self.kind, self.schema = kind, schema
        self.messages = logs.setdefault(topic, [])

    def has_sinks(self) -> bool:
        return True

    def log(self, msg: Any) -> None:
        self.messages.append(msg)


def logged_fleet(logs: dict[str, list[Any]], clock: list[float], poses: dict[str, bytes]) -> FleetView:
    def channel(topic: str, kind: Kind, schema: dict[str, Any] | None) -> Logged:
        return Logged(topic, kind, schema, logs)

    robots = [(rid, Keys(f"fleet/{rid}"), None, 10) for rid in IDS]
    return FleetView(robots, clock=lambda: clock[0], channel=channel, poses=poses.get)


def test_the_fleet_view_names_each_robots_channels_under_its_id_on_one_tf() -> None:
    logs: dict[str, list[Any]] = {}
    view = logged_fleet(logs, [0.0], {})
    assert {"/tf", f"{FLEET_NAMESPACE}/summary", f"{FLEET_NAMESPACE}/log", "/r2/pose", "/r3/robot_description"} <= set(logs)
    assert "/r1/tf" not in logs, "one /tf for the fleet"
    assert view.views["r2"].frame == "r2/odom" and view.views["r2"].base == "r2/base_footprint"
    feeds = view.feeds()
    assert feeds["fleet/r2/gateway/health"] == {"/r2/health", "/r2/diagnostics", "/fleet/summary", "/fleet/log"}
    assert "/tf" in feeds["fleet/r1/pose"] and "/r1/path" in feeds["fleet/r1/pose"]
    assert FLEET_SUMMARY_SCHEMA["title"] == "FleetSummary"


def test_a_robot_lost_and_back_is_a_line_on_the_fleets_log_and_a_summary_at_once() -> None:
    logs: dict[str, list[Any]] = {}
    clock = [10.0]
    poses = {"r1": encode(Pose(stamp=9.0, x=3.0, y=4.0, yaw=0.0))}
    view = logged_fleet(logs, clock, poses)
    on_health = view.handlers("r1")["fleet/r1/gateway/health"]
    on_health(encode(_health(9.5)))
    (summary,) = logs["/fleet/summary"]
    row = json.loads(summary)["robots"][0]
    assert (row["id"], row["link"], row["x"], row["y"]) == ("r1", "connected/connected", 3.0, 4.0), "the latest pose, read when made"
    clock[0] = 10.5
    on_health(encode(_health(10.0)))
    assert len(logs["/fleet/summary"]) == 1, "at most once a second on health alone"
    view.on_token("r1", False)
    (line,) = logs["/fleet/log"]
    assert b"r1 lost: its gateway left (liveliness token gone)" in line.encode() and b"fleet" in line.encode()
    assert len(logs["/fleet/summary"]) == 2, "a robot lost sends the summary at once"
    clock[0] = 11.0
    on_health(encode(_health(10.5)))
    assert b"r1 back: its gateway's health arrives again" in logs["/fleet/log"][-1].encode()
    view.on_fleet_error(ErrorReport(stamp=11.0, source="foxglove", key="foxglove:/cmd_vel", reason="names no robot"))
    assert b"foxglove:/cmd_vel: names no robot" in logs["/fleet/log"][-1].encode()
    on_health(b"not a health")  # skipped, never raised
