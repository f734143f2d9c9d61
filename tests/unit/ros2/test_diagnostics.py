"""ROS 2 ``/diagnostics`` (:mod:`blackmetal.ros2.diagnostics`): the level and words a user sees for each condition.

The statuses are built here straight from :class:`Diagnostics`, fed on a
fake clock; the core publishing them at 1 Hz, read back from the CDR, is
tests/unit/ros2/test_services.py.
"""

from __future__ import annotations

from typing import Any

import pytest

from blackmetal.robot_model import Encoders
from blackmetal.ros2.diagnostics import AdapterStats, Diagnostics, WindowCount
from blackmetal.ros2.options import Ros2Options
from blackmetal.ros2.ros_types import Frames
from blackmetal.runtime.diagnostics import POSE_LATE_S, WINDOW_S, Level
from blackmetal.schemas import ErrorReport, GatewayHealth, Keys, LinkHealth

KEYS = Keys("r1")


def diagnostics() -> Diagnostics:
    d = Diagnostics(KEYS, node="/ns/blackmetal", expected_poll_hz=50.0)
    d.on_alive("gateway", True)
    d.on_alive("odometry", True)
    return d


def health(**fields: Any) -> GatewayHealth:
    base: dict[str, Any] = {"stamp": 0.0, "control": LinkHealth("connected"), "log": LinkHealth("connected"), "poll_hz": 50.0}
    return GatewayHealth(**{**base, **fields})


def test_a_healthy_link_is_ok_and_named_after_the_node() -> None:
    d = diagnostics()
    d.on_health(health(last_rtt_ms=3.0, source="run1"), now=1.0)
    status = d.robot_link(1.5)
    assert (status.level, status.name, status.message, status.hardware_id) == (
        Level.OK,
        "ns/blackmetal: robot link",
        "connected, polling at 50 Hz",
        "r1",
    )
    assert dict(status.values)["gateway alive"] == "yes" and dict(status.values)["health age (s)"] == "0.5"


def test_an_engaged_estop_is_an_error_saying_since_when_and_by_whom() -> None:
    d = diagnostics()
    d.on_health(health(estop=True, estop_since=0.0, estop_by="r1/estop"), now=1.0)
    status = d.robot_link(1.0)
    assert status.level == Level.ERROR
    assert status.message == "e-stop engaged since 1970-01-01 00:00:00 UTC by r1/estop"
    assert dict(status.values)["e-stop"] == "engaged" and dict(status.values)["e-stop by"] == "r1/estop"


@pytest.mark.parametrize(
    ("fields", "level", "message"),
    [
        ({"poll_hz": 45.0}, Level.OK, "connected, polling at 45 Hz"),  # 90 % of the asked rate is still fine
        ({"poll_hz": 40.0}, Level.WARN, "polling at 40 Hz of 50 Hz"),
        ({"poll_hz": 20.0}, Level.ERROR, "polling at 20 Hz of 50 Hz"),
        ({"last_rtt_ms": 150.0}, Level.WARN, "round trip 150 ms"),
        ({"last_rtt_ms": 251.0}, Level.ERROR, "round trip 251 ms"),
        ({"log": LinkHealth("connecting")}, Level.WARN, "log link connecting"),
        ({"control": LinkHealth("down"), "poll_hz": 0.0}, Level.ERROR, "control link down"),  # not also "polling at 0 Hz"
        ({"conflict_with": "host-b"}, Level.ERROR, "another gateway (host-b) on r1: commands refused"),
    ],
)
def test_each_condition_of_the_link_has_its_level_and_words(fields: dict[str, Any], level: Level, message: str) -> None:
    d = diagnostics()
    d.on_health(health(**fields), now=1.0)
    assert (d.robot_link(1.0).level, d.robot_link(1.0).message) == (level, message)


def test_the_worst_condition_comes_first() -> None:
    d = diagnostics()
    d.on_health(health(log=LinkHealth("down"), last_rtt_ms=300.0), now=1.0)
    assert d.robot_link(1.0).message == "round trip 300 ms; log link down"


def test_lost_replies_count_over_the_window_and_start_over_with_a_new_gateway_run() -> None:
    d = diagnostics()
    d.on_health(health(source="run1", lost_replies=5, polls=1000), now=0.0)
    d.on_health(health(source="run1", lost_replies=6, polls=1100), now=1.0)
    assert (d.robot_link(1.0).level, d.robot_link(1.0).message) == (Level.WARN, f"1 of 100 replies lost in {WINDOW_S:g} s")
    d.on_health(health(source="run1", lost_replies=25, polls=1200), now=2.0)  # 20 of 200 in the window: severe
    assert d.robot_link(2.0).level == Level.ERROR
    d.on_health(health(source="run2", lost_replies=0, polls=10), now=3.0)  # restarted: its counters are no loss
    assert d.lost_in_window(3.0) == (0, 0) and d.robot_link(3.0).level == Level.OK
    d.on_health(health(source="run2", lost_replies=0, polls=60), now=4.0)
    d.on_health(health(source="run2", lost_replies=1, polls=110), now=3.5 + WINDOW_S)
    assert d.lost_in_window(3.5 + WINDOW_S) == (1, 50)  # the report at 3.0 fell out of the window


def test_nothing_heard_yet_is_stale_and_a_process_gone_is_an_error_naming_its_key() -> None:
    d = Diagnostics(KEYS, node="/blackmetal", expected_poll_hz=50.0)
    link, odometry = d.robot_link(0.0), d.odometry(0.0)
    assert (link.level, link.message) == (Level.STALE, "no gateway health yet on r1/gateway/health")
    assert (odometry.level, odometry.message) == (Level.STALE, "no pose yet on r1/pose")
    assert dict(link.values)["gateway alive"] == "unknown" and dict(odometry.values)["pose age (s)"] == "never"
    d.on_alive("gateway", False)
    d.on_alive("odometry", False)
    assert d.robot_link(0.0).message == "the gateway is not running (no r1/alive/gateway)"
    assert d.odometry(0.0).message == "the odometry is not running (no r1/alive/odometry)"
    assert d.robot_link(0.0).level == d.odometry(0.0).level == Level.ERROR


def test_a_late_pose_warns_before_it_goes_stale() -> None:
    d = diagnostics()
    d.on_pose(now=10.0)
    assert (d.odometry(10.0 + POSE_LATE_S).level, d.odometry(10.0 + POSE_LATE_S).message) == (Level.OK, "publishing poses")
    assert (d.odometry(11.0).level, d.odometry(11.0).message) == (Level.WARN, "last pose 1.0 s ago")
    assert d.odometry(12.5).level == Level.STALE


def test_only_the_odometrys_reports_on_the_impulses_are_rejected_samples() -> None:
    d = diagnostics()
    d.on_pose(now=1.0)
    d.on_error_report(ErrorReport(stamp=0.0, source="odometry", key=KEYS.pose, reason="elsewhere"), now=1.0)
    d.on_error_report(ErrorReport(stamp=0.0, source="gateway", key=KEYS.impulses, reason="not the odometry's"), now=1.0)
    assert d.odometry(1.0).level == Level.OK and d.rejected.total == 0
    d.on_error_report(ErrorReport(stamp=0.0, source="odometry", key=KEYS.impulses, reason="seq went back"), now=1.0)
    status = d.odometry(1.0)
    assert (status.level, status.message) == (Level.WARN, f"1 impulse samples rejected in {WINDOW_S:g} s")
    assert dict(status.values)["last rejection"] == "seq went back"
    d.on_pose(now=1.0 + WINDOW_S)
    assert d.odometry(1.0 + WINDOW_S).level == Level.OK and d.rejected.total == 1  # out of the window, still counted


def test_a_window_count_forgets_events_older_than_its_window() -> None:
    count = WindowCount(window=10.0)
    count.add(0.0)
    count.add(5.0, 3)
    assert (count.recent(9.9), count.recent(10.0), count.recent(15.0), count.total) == (4, 3, 0, 4)


def test_the_adapters_status_warns_on_bad_inputs_and_failed_calls() -> None:
    options = Ros2Options(Frames(), [0.0] * 36, [0.0] * 36, False, ("l", "r"), 0.1, Encoders(), calibration="cal.json")
    d, stats = diagnostics(), AdapterStats()
    status = d.adapter(0.0, stats, options, pending=0)
    assert (status.level, status.name, status.message) == (Level.OK, "ns/blackmetal: ROS 2 adapter", "running; calibration cal.json")
    assert dict(status.values)["cmd_vel to"] == "r1/cmd_vel/ros2" and dict(status.values)["robot model"] == "not published"
    stats.bad_inputs.add(1.0, 2)
    stats.failed.add(1.0)
    status = d.adapter(1.0, stats, options, pending=3)
    assert status.level == Level.WARN
    assert status.message == f"2 bad ROS inputs in {WINDOW_S:g} s (reported on r1/errors); 1 service calls failed in {WINDOW_S:g} s"
    assert dict(status.values)["service calls pending"] == "3"
