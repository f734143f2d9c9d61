"""The clients' inputs of the gateway's core (commands by source, locks, the e-stop's keys, drivers) on a fake clock."""

from __future__ import annotations

import itertools
import math

import pytest

from blackmetal.gateway.estop import read_estop
from blackmetal.schemas import ErrorReport
from blackmetal.wire import CommandCode

from .test_core import Bench, twist_payload


def test_the_operator_holds_the_robot_while_navigation_publishes_and_nothing_jumps() -> None:
    bench = Bench()
    bench.connect()
    for k in range(100):  # 5 s: nav at 20 Hz wants 0.3 m/s, the operator at 10 Hz holds 0
        bench.conn.on_cmd_vel("nav", twist_payload(0.3), bench.t)
        if k % 2 == 0:
            bench.conn.on_cmd_vel("teleop", twist_payload(0.0), bench.t)
        bench.settle()
        bench.run(0.05)
    assert all(left == right == 0.0 for _, left, right in bench.velocity())  # not one motion command
    bench.robot.advance(bench.t)
    assert math.hypot(bench.robot.x, bench.robot.y) == 0.0
    health = bench.conn.health(bench.t)
    assert health.active_source == "teleop" and health.sources["nav"].dropped >= 99 and health.sources["teleop"].dropped == 0
    assert health.sources["foxglove"].age is None and not bench.of(ErrorReport)  # dropped quietly


def test_when_the_operator_lets_go_navigation_takes_over_through_the_acceleration_limit() -> None:
    bench = Bench(linear_accel=1.0)
    bench.connect()
    for _ in range(10):
        bench.conn.on_cmd_vel("nav", twist_payload(0.3), bench.t)
        bench.conn.on_cmd_vel("teleop", twist_payload(0.0), bench.t)
        bench.settle()
        bench.run(0.05)
    released = bench.t  # the operator stops publishing; nav goes on
    for _ in range(30):
        bench.conn.on_cmd_vel("nav", twist_payload(0.3), bench.t)
        bench.settle()
        bench.run(0.05)
    moving = [(t, left) for t, left, _ in bench.velocity() if left > 0]
    assert moving and moving[0][0] - released <= 0.5 + 0.05  # within the operator's timeout
    assert bench.conn.health(bench.t).active_source == "nav"
    speeds = [(t, left) for t, left, _ in bench.velocity() if t >= released]
    for (t0, a), (t1, b) in itertools.pairwise(speeds):
        assert b - a <= 1.0 * (t1 - t0) + 1e-6  # never faster than the 1 m/s^2 limit
    assert speeds[-1][1] == pytest.approx(0.3)


def test_the_estop_is_above_every_source_and_unknown_sources_are_named() -> None:
    bench = Bench()
    bench.connect()
    bench.conn.on_cmd_vel("teleop", twist_payload(0.2), bench.t)
    bench.conn.on_estop(read_estop(b'{"engaged": true}'), bench.t)
    bench.conn.on_cmd_vel("teleop", twist_payload(0.2), bench.t)
    bench.settle()
    bench.run(0.2)
    assert bench.count(CommandCode.EMG_STOP) == 1 and any("emergency stop is engaged" in e.reason for e in bench.of(ErrorReport))
    bench.conn.on_cmd_vel("joystick", twist_payload(0.1), bench.t)
    bench.settle()
    unknown = [e for e in bench.of(ErrorReport) if e.key == "robot/cmd_vel/joystick"]
    assert unknown and "teleop, foxglove, default, ros2, nav" in unknown[0].reason


def test_a_heartbeat_lock_that_is_not_refreshed_stops_the_robot_within_its_timeout() -> None:
    bench = Bench(lock=["supervisor:255:0.3"], cmd_timeout=0.0)
    bench.connect()
    bench.conn.on_cmd_vel("teleop", twist_payload(0.2), bench.t)
    bench.settle()
    assert all(left == 0.0 for _, left, _ in bench.velocity())  # no heartbeat yet: the lock holds the robot
    for _ in range(10):
        bench.conn.on_lock("supervisor", b'{"locked": false}', bench.t)
        bench.conn.on_cmd_vel("teleop", twist_payload(0.2), bench.t)
        bench.settle()
        bench.run(0.1)
    assert bench.velocity()[-1][1:] == (0.2, 0.2)
    last_beat = bench.t - 0.1
    bench.run(1.0)  # the supervisor died; teleop would go on, the lock stops it
    stop = next(t for t, left, _ in bench.velocity() if t > last_beat and left == 0.0)
    assert stop - last_beat <= 0.3 + 1e-6
    assert bench.conn.health(bench.t).locks == {"supervisor": True}
    bench.conn.on_lock("nosuch", b'{"locked": true}', bench.t)
    bench.conn.on_lock("supervisor", b'{"locked": "yes"}', bench.t)
    bench.settle()
    reasons = [e.reason for e in bench.of(ErrorReport)]
    assert any("unknown lock 'nosuch': the gateway's locks are supervisor" in r for r in reasons)
    assert any('send {"locked": true} or {"locked": false}' in r for r in reasons)


def test_a_release_counts_only_on_the_release_key_by_default() -> None:
    bench = Bench()
    bench.connect()
    bench.conn.on_estop(read_estop(b'{"engaged": true}'), bench.t)
    bench.conn.on_estop(read_estop(b'{"engaged": false}'), bench.t)  # on estop: refused, reported, the stop stays
    bench.settle()
    assert bench.conn.governor.estop
    (report,) = [e for e in bench.of(ErrorReport) if e.key == "robot/estop"]
    assert 'only {"engaged": false} put on robot/estop/release releases' in report.reason
    bench.conn.on_estop(read_estop(b'{"engaged": false}', release_key=True), bench.t)
    bench.settle()
    assert not bench.conn.governor.estop
    bench.conn.on_estop(read_estop(b"garbage", release_key=True), bench.t)  # anything but a release engages, on either key
    assert bench.conn.governor.estop


def test_the_unsafe_setting_lets_a_release_on_estop_release() -> None:
    bench = Bench(unsafe_release_on_estop=True)
    bench.connect()
    bench.conn.on_estop(read_estop(b'{"engaged": true}'), bench.t)
    bench.settle()
    bench.conn.on_estop(read_estop(b'{"engaged": false}'), bench.t)
    bench.settle()
    assert not bench.conn.governor.estop and not bench.of(ErrorReport)


def test_every_change_of_driver_is_published_with_who_from_whom_and_why() -> None:
    from blackmetal.schemas import DriverChange

    bench = Bench(lock=["pause:200"])
    bench.connect()
    bench.conn.on_cmd_vel("nav", twist_payload(0.2), bench.t)
    bench.run(0.1)
    bench.conn.on_cmd_vel("teleop", twist_payload(0.1), bench.t)
    bench.run(0.1)
    bench.conn.on_lock("pause", b'{"locked": true}', bench.t)
    bench.run(0.1)
    bench.conn.on_lock("pause", b'{"locked": false}', bench.t)
    bench.run(1.0)  # teleop fell silent
    changes = [(d.source, d.previous) for d in bench.of(DriverChange)]
    assert changes == [("nav", None), ("teleop", "nav"), (None, "teleop"), ("teleop", None), (None, "teleop")]
    reasons = [d.reason for d in bench.of(DriverChange)]
    assert "outranks nav (priority 10)" in reasons[1] and "lock" in reasons[2] and "fell silent" in reasons[4]


def test_a_malformed_or_unknown_parameter_set_is_refused_with_the_reason() -> None:
    bench = Bench()
    why = bench.conn.on_params_set(b"not json", bench.t)
    assert isinstance(why, str) and 'send {"values": {"max_wheel_speed": 0.3}}' in why
    reply = bench.conn.on_params_set(b'{"values": {"max_wheel_speed": 0.3, "nosuch": 1}}', bench.t)
    assert not isinstance(reply, str)
    assert [(r.name, r.successful) for r in reply.results] == [("max_wheel_speed", True), ("nosuch", False)]
    assert bench.conn.governor.settings.max_wheel_speed == pytest.approx(0.3)
    assert bench.conn.counters.rejected_inputs == 2


def test_superseded_commands_are_counted_per_source_and_reported() -> None:
    bench = Bench()
    bench.conn.on_superseded("nav", 7, bench.t)
    bench.settle()
    assert bench.conn.health(bench.t).sources["nav"].superseded == 7
    assert any("7 commands from source 'nav' were superseded" in e.reason for e in bench.of(ErrorReport))
    assert bench.count(CommandCode.SET_LR_WHEEL_VELOCITY) == 0
