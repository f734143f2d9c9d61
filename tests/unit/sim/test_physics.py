"""The simulated robot's physics and command handling, on a fake clock."""

from __future__ import annotations

import math

import pytest

from blackmetal import robot_model as facts
from blackmetal import wire
from blackmetal.robot_model import arc_step
from blackmetal.schemas import SimFaults
from blackmetal.sim.physics import RobotParams, SimRobot
from blackmetal.wire import CommandCode, PositionReading, ReplyDecoder, SpeedReading, StatusReply


def send(robot: SimRobot, request: wire.Request, now: float) -> list[object]:
    decoder = ReplyDecoder()
    return [item for wire in robot.handle(request, now) for item in decoder.feed(wire)]


def test_straight_line_is_exact() -> None:
    robot = SimRobot()
    assert send(robot, wire.set_velocity(left=0.2, right=0.2), 0.0) == [StatusReply("RECIEVE_OK")]
    robot.advance(5.0)
    assert robot.x == pytest.approx(1.0, abs=1e-12)
    assert robot.y == pytest.approx(0.0, abs=1e-12)
    pose = robot.pose(123.0)
    assert pose.v == pytest.approx(0.2) and pose.w == pytest.approx(0.0) and pose.stamp == 123.0


def test_left_turn_on_a_circle_matches_the_closed_form() -> None:
    robot = SimRobot()
    v_r, v_l, sep = 0.3, 0.1, facts.WHEEL_SEPARATION
    send(robot, wire.set_velocity(left=v_l, right=v_r), 0.0)
    w = (v_r - v_l) / sep
    radius = 0.5 * (v_r + v_l) / w
    for t in (0.37, 1.0, 2.5, 7.9):
        robot.advance(t)
        assert robot.x == pytest.approx(radius * math.sin(w * t), abs=1e-9)
        assert robot.y == pytest.approx(radius * (1 - math.cos(w * t)), abs=1e-9)
    assert robot.y > 0  # +z / right wheel faster turns left (REP-103)


def test_arc_step_straight_limit_is_continuous() -> None:
    straight = arc_step(0.0, 0.0, 0.3, 1.0, 1.0, 0.5)
    almost = arc_step(0.0, 0.0, 0.3, 1.0, 1.0 + 1e-9, 0.5)
    assert straight == pytest.approx(almost, abs=5e-9)  # the turn itself moves y by ~1e-9


def test_watchdog_stops_the_robot_ten_seconds_after_the_last_motion_command() -> None:
    robot = SimRobot()
    send(robot, wire.set_velocity(left=0.1, right=0.1), 0.0)
    for t in range(1, 9):  # polls do not count as commands for the watchdog
        send(robot, wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY), float(t))
    robot.advance(9.999)
    assert robot.moving
    robot.advance(30.0)
    assert not robot.moving
    assert robot.x == pytest.approx(1.0, abs=1e-12)  # exactly 10 s at 0.1 m/s
    assert robot.counters["watchdog_stops"] == 1


def test_repeating_the_command_keeps_the_robot_going() -> None:
    robot = SimRobot()
    for t in range(0, 30, 5):
        send(robot, wire.set_velocity(left=0.1, right=0.1), float(t))
    robot.advance(30.0)
    assert robot.moving and robot.x == pytest.approx(3.0)


def test_emergency_stop_is_immediate_even_with_an_acceleration_limit() -> None:
    robot = SimRobot(RobotParams(accel_limit=0.5))
    send(robot, wire.set_velocity(left=0.4, right=0.4), 0.0)
    robot.advance(2.0)
    assert robot.speed_left == pytest.approx(0.4)
    send(robot, wire.simple(CommandCode.EMG_STOP), 2.0)
    assert robot.speed_left == robot.speed_right == 0.0
    x = robot.x
    robot.advance(3.0)
    assert robot.x == x


def test_acceleration_limit_ramps_and_normal_stop_decelerates() -> None:
    robot = SimRobot(RobotParams(accel_limit=0.5))
    send(robot, wire.set_velocity(left=0.4, right=0.4), 0.0)
    robot.advance(0.4)
    assert robot.speed_left == pytest.approx(0.2, abs=1e-9)
    robot.advance(2.0)
    # 0.8 s ramp covers 0.16 m, then 1.2 s at 0.4 m/s
    assert robot.x == pytest.approx(0.16 + 0.48, abs=1e-6)
    send(robot, wire.simple(CommandCode.NORMAL_STOP), 2.0)
    robot.advance(2.4)
    assert robot.speed_left == pytest.approx(0.2, abs=1e-9)
    robot.advance(5.0)
    assert not robot.moving
    assert robot.x == pytest.approx(0.64 + 0.16, abs=1e-6)


def test_wheel_speed_is_clamped_to_the_robots_limit() -> None:
    robot = SimRobot()
    send(robot, wire.set_velocity(left=-1.0, right=1.0), 0.0)
    assert robot.speed_right == facts.MAX_WHEEL_SPEED
    assert robot.speed_left == -facts.MAX_WHEEL_SPEED


def test_speed_reply_reports_mirrored_integer_impulses_without_bias() -> None:
    robot = SimRobot()
    send(robot, wire.set_velocity(left=0.2, right=0.2), 0.0)
    readings = [send(robot, wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY), 0.005 * i)[1] for i in range(1, 1001)]
    assert all(isinstance(r, SpeedReading) for r in readings)
    lefts = [r.left for r in readings]  # type: ignore[union-attr]
    rights = [r.right for r in readings]  # type: ignore[union-attr]
    assert set(lefts) <= {202, 203} and set(rights) <= {-211, -210}
    assert sum(lefts) / len(lefts) == pytest.approx(0.2 * facts.IMPULSES_PER_METER_LEFT, abs=2e-3)
    assert -sum(rights) / len(rights) == pytest.approx(0.2 * facts.IMPULSES_PER_METER_RIGHT, abs=2e-3)


def test_a_wheel_larger_than_its_drawing_runs_fast_and_reports_the_commanded_impulses() -> None:
    # the firmware turns m/s into impulses with the nominal constants: the left wheel, 1.5 % larger, really runs 1.5 % fast
    robot = SimRobot(RobotParams.with_wheel_scales(left=1.015, right=1.0))
    send(robot, wire.set_velocity(left=0.2, right=0.2), 0.0)
    readings = [send(robot, wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY), 0.01 * i)[1] for i in range(1, 501)]
    lefts = [r.left for r in readings]  # type: ignore[union-attr]
    assert sum(lefts) / len(lefts) == pytest.approx(0.2 * facts.IMPULSES_PER_METER_LEFT, abs=2e-3)
    assert robot.travel_left == pytest.approx(0.2 * 1.015 * 5.0) and robot.travel_right == pytest.approx(1.0)
    assert robot.yaw < 0  # the larger left wheel turns the robot to the right


def test_position_command_moves_each_wheel_by_its_impulses() -> None:
    robot = SimRobot()
    left_imp = round(0.3 * facts.IMPULSES_PER_METER_LEFT)
    right_imp = round(0.3 * facts.IMPULSES_PER_METER_RIGHT)
    send(robot, wire.Request(CommandCode.SET_LR_WHEEL_POSITION, left=left_imp, right=right_imp), 0.0)
    robot.advance(0.5)
    assert robot.moving
    robot.advance(3.0)
    assert not robot.moving
    assert robot.x == pytest.approx(0.3, abs=1e-3)
    replies = send(robot, wire.simple(CommandCode.GET_LR_WHEEL_POSITION), 3.0)
    assert replies[1] == PositionReading(left=left_imp, right=-right_imp)


def test_status_reply_for_every_command_and_data_only_for_gets() -> None:
    robot = SimRobot()
    for command in CommandCode:
        if command in (CommandCode.SET_LR_WHEEL_VELOCITY, CommandCode.SET_LR_WHEEL_POSITION):
            continue
        replies = send(robot, wire.simple(command), 0.0)
        assert replies[0] == StatusReply("RECIEVE_OK")
        assert len(replies) == (2 if command in wire.DATA_COMMANDS else 1)


def test_full_buffer_fault_drops_the_command() -> None:
    robot = SimRobot(seed=1)
    robot.faults = SimFaults(full_buffer=1.0)
    assert send(robot, wire.set_velocity(left=0.2, right=0.2), 0.0) == [StatusReply("FULL_BUFFER")]
    assert send(robot, wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY), 0.0) == [StatusReply("FULL_BUFFER")]
    assert not robot.moving
    robot.faults = SimFaults()
    send(robot, wire.set_velocity(left=0.2, right=0.2), 0.0)
    assert robot.moving


def test_dropout_and_spike_faults_corrupt_readings_only() -> None:
    robot = SimRobot(seed=3)
    send(robot, wire.set_velocity(left=0.2, right=0.2), 0.0)
    robot.faults = SimFaults(dropout=1.0)
    assert robot.read_impulses() == (0, 0)
    robot.faults = SimFaults(spike=1.0)
    left, right = robot.read_impulses()
    assert left > facts.MAX_WHEEL_SPEED * facts.IMPULSES_PER_METER_LEFT
    assert -right > facts.MAX_WHEEL_SPEED * facts.IMPULSES_PER_METER_RIGHT
    robot.faults = SimFaults()
    robot.advance(1.0)
    assert robot.x == pytest.approx(0.2)  # the truth never saw the faults
