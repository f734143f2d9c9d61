"""Position moves through the gateway's core (:mod:`blackmetal.gateway.moves`), against the simulator's physics on a fake clock.

A move is asked on ``wheels/move``; the gateway reads the wheels' positions, sends SET_LR_WHEEL_POSITION, and
publishes the progress on ``wheels/position`` until the wheels stand at the target. What refuses a move and what
ends one is docs/safety.md "Position moves".
"""

from __future__ import annotations

import itertools
import json
import math
from typing import Any

import pytest

from blackmetal import wire
from blackmetal.gateway.position import DEADLINE_FACTOR, DEADLINE_MARGIN_S, MAX_TRAVEL_M, STALL_S
from blackmetal.schemas import (
    DriverChange,
    ErrorReport,
    GatewayHealth,
    MoveState,
    SimFaults,
    WheelImpulses,
    WheelMoveReply,
    WheelPosition,
    encode,
)
from blackmetal.sim.physics import RobotParams, SimRobot
from blackmetal.wire import CommandCode, Request

from .test_core import Bench, twist_payload

SEPARATION = 0.5


def moving_bench(robot: SimRobot | None = None, **settings: Any) -> Bench:
    """A connected bench whose gateway runs position moves; half a second in, standing."""
    bench = Bench(robot, **{"position_moves": True, **settings})
    bench.connect()
    bench.run(0.5)
    return bench


def ask(bench: Bench, left: float, right: float, **fields: Any) -> WheelMoveReply:
    reply = bench.conn.on_wheel_move(json.dumps({"left": left, "right": right, **fields}).encode(), bench.t)
    bench.settle()
    return reply


def positions(bench: Bench) -> list[WheelPosition]:
    return bench.of(WheelPosition)


def errors(bench: Bench) -> list[str]:
    return [e.reason for e in bench.of(ErrorReport)]


def sent(bench: Bench, since: float = -math.inf) -> list[tuple[float, Request]]:
    """Motion commands the robot received since ``since`` (polls and PREPARE left out)."""
    polls = (CommandCode.GET_LR_WHEEL_VELOCITY, CommandCode.GET_LR_WHEEL_POSITION, CommandCode.PREPARE_WHEEL_CONTROLLER)
    return [(t, r) for t, r in bench.requests if t >= since and r.command not in polls]


def test_a_metre_forward_runs_on_the_robot_and_is_published_until_done() -> None:
    bench = moving_bench()
    start = bench.t
    reply = ask(bench, 1.0, 1.0)
    assert reply.accepted and reply.reason == "" and len(reply.move_id or "") == 32
    assert (reply.left_impulses, reply.right_impulses) == (1013, 1054)  # metres times the calibrated impulses per metre
    assert reply.expected == pytest.approx(1.0 / 0.3, abs=0.01) and reply.deadline == pytest.approx(reply.expected * 1.5 + 1.0, abs=0.01)
    # the first reading is asked before the command, so the start is where the wheels stood
    codes = [r.command for t, r in bench.requests if t >= start and r.command is not CommandCode.GET_LR_WHEEL_VELOCITY]
    assert codes[:2] == [CommandCode.GET_LR_WHEEL_POSITION, CommandCode.SET_LR_WHEEL_POSITION]
    bench.run(5.0)
    assert bench.robot.travel_left == pytest.approx(1.0, abs=0.002) and bench.robot.travel_right == pytest.approx(1.0, abs=0.002)
    assert bench.robot.x == pytest.approx(1.0, abs=0.002) and abs(bench.robot.yaw) < 0.002
    published = positions(bench)
    assert {p.move_id for p in published} == {reply.move_id} and all(p.source == "nav" for p in published)
    assert [p.state for p in published[:-1]] == [MoveState.RUNNING] * (len(published) - 1) and published[-1].state is MoveState.DONE
    done = published[-1]
    assert (done.left, done.right) == (done.target_left, done.target_right) == (1013, -1054)  # as the robot reports: right mirrored
    assert done.elapsed == pytest.approx(reply.expected, abs=0.15)  # done within a few readings of the wheels stopping
    during = [p.stamp - 1_800_000_000.0 for p in published if p.state is MoveState.RUNNING]
    assert len(during) / (during[-1] - during[0]) >= 20.0  # progress at the position poll rate
    readings = [m.mono for m in bench.of(WheelImpulses) if m.mono is not None and start < m.mono < start + 3.0]
    assert len(readings) >= 49 * 3  # the velocity polls (the odometry's) go on at their rate beside
    assert [r.command for _, r in sent(bench, start)] == [CommandCode.SET_LR_WHEEL_POSITION]
    counters = bench.robot.counters
    assert errors(bench) == [] and counters["watchdog_stops"] == 0 and counters["position_commands"] == 1
    assert counters["position_polls"] == len(published) and counters["polls"] >= 2 * len(published)
    assert bench.conn.health(bench.t).last_sent == "position 1013 1054"


def test_a_turn_on_the_spot_turns_the_robot_by_its_angle() -> None:
    bench = moving_bench()
    half = math.pi / 2 * SEPARATION / 2
    assert ask(bench, -half, half).accepted
    bench.run(3.0)
    assert math.degrees(bench.robot.yaw) == pytest.approx(90.0, abs=0.2)
    assert math.hypot(bench.robot.x, bench.robot.y) < 0.002 and positions(bench)[-1].state is MoveState.DONE


def test_a_long_move_goes_out_in_segments_the_watchdog_never_cuts() -> None:
    bench = moving_bench()
    reply = ask(bench, 5.0, 5.0)
    assert reply.expected == pytest.approx(16.67, abs=0.01)
    bench.run(20.0)
    commands = sent(bench, 0.5)
    assert [r.command for _, r in commands] == [CommandCode.SET_LR_WHEEL_POSITION] * 4  # 16.7 s at most 5 s (keepalive) each
    assert max(b - a for (a, _), (b, _) in itertools.pairwise(commands)) <= 5.0  # never a command older than the keep-alive
    assert sum(int(r.left or 0) for _, r in commands) == 5063 and sum(int(r.right or 0) for _, r in commands) == 5268
    assert bench.robot.counters["watchdog_stops"] == 0 and bench.robot.x == pytest.approx(5.0, abs=0.003)
    assert positions(bench)[-1].state is MoveState.DONE and positions(bench)[-1].elapsed < reply.expected + 0.5
    # the move holds its source live in the arbiter for as long as it runs; it falls silent after
    changes = [c.reason for c in bench.of(DriverChange)]
    assert changes == ["nav (priority 10) drives: nobody drove", "nav (priority 10) fell silent for 0.5 s: nobody drives"]
    assert bench.of(DriverChange)[-1].stamp - 1_800_000_000.0 >= 0.5 + positions(bench)[-1].elapsed


def test_a_backward_move_and_a_given_id_and_source() -> None:
    bench = moving_bench(source=["default:50", "nav:10", "dock:20"])
    move_id = "ab" * 16
    reply = ask(bench, -0.3, -0.3, source="dock", move_id=move_id)
    assert reply.accepted and reply.move_id == move_id and reply.left_impulses < 0
    bench.run(2.0)
    assert bench.robot.x == pytest.approx(-0.3, abs=0.002)
    assert positions(bench)[-1].source == "dock" and positions(bench)[-1].move_id == move_id


# --------------------------------------------------------------------------- refusals


def refused(bench: Bench, payload: bytes) -> str:
    """The reason a move is refused; it is reported on wheels/move, and nothing reaches the robot."""
    before, reports = len(bench.requests), len(bench.of(ErrorReport))
    reply = bench.conn.on_wheel_move(payload, bench.t)
    bench.settle()
    assert not reply.accepted and reply.reason
    assert [r.command for _, r in bench.requests[before:]] in ([], [CommandCode.GET_LR_WHEEL_VELOCITY])
    report = bench.of(ErrorReport)[reports:]
    assert report and report[-1].key == "robot/wheels/move" and report[-1].reason == reply.reason
    assert bench.conn.move is None
    return reply.reason


def test_position_moves_are_off_unless_the_settings_say_the_robot_supports_them() -> None:
    bench = Bench()
    bench.connect()
    assert "position moves are off" in refused(bench, b'{"left": 1, "right": 1}')
    assert "--position-moves" in refused(bench, b'{"left": 1, "right": 1}')


@pytest.mark.parametrize(
    ("payload", "why"),
    [
        (b"", "payload is empty"),
        (b'{"left": NaN, "right": 1}', "not valid JSON"),
        (b'{"left": 1e999, "right": 1}', "not finite"),
        (b'{"left": "far", "right": 1}', "float"),
        (b'{"left": 1}', "right"),
        (b'{"left": 1, "right": 1, "source": "ghost"}', "unknown command source 'ghost'"),
        (b'{"left": 30, "right": 30}', f"beyond the {MAX_TRAVEL_M:g} m a position move may take"),
        (b'{"left": 1, "right": -25.5}', "25.5 m"),
    ],
)
def test_a_bad_move_is_refused_with_a_sentence(payload: bytes, why: str) -> None:
    assert why in refused(moving_bench(), payload)


def test_a_move_is_refused_while_the_estop_is_engaged() -> None:
    bench = moving_bench()
    bench.conn.on_estop(*_estop(True), bench.t)
    bench.settle()
    assert "emergency stop is engaged" in refused(bench, b'{"left": 1, "right": 1}')


def _estop(engaged: bool) -> tuple[Any]:
    from blackmetal.gateway.estop import read_estop

    return (read_estop(json.dumps({"engaged": engaged}).encode(), release_key=not engaged),)


def test_a_move_is_refused_while_the_link_is_down() -> None:
    bench = moving_bench()
    bench.conn.link_down("control", "closed by the robot", bench.t)
    assert "control link is down" in refused(bench, b'{"left": 1, "right": 1}')


def test_a_move_is_refused_while_a_higher_source_drives_or_a_lock_blocks_its_source() -> None:
    bench = moving_bench(lock=["dock:20"])
    bench.conn.on_cmd_vel("teleop", twist_payload(0.0), bench.t)
    bench.settle()
    assert refused(bench, b'{"left": 1, "right": 1}') == "teleop (priority 100) drives: a move of nav (priority 10) would be outranked"
    bench.run(1.0)  # teleop fell silent
    bench.conn.on_lock("dock", b'{"locked": true}', bench.t)
    assert refused(bench, b'{"left": 1, "right": 1}') == "a lock blocks source 'nav' (priority 10): its position move is refused"
    bench.conn.on_lock("dock", b'{"locked": false}', bench.t)
    assert ask(bench, 0.1, 0.1).accepted


def test_a_move_starts_from_standstill_only() -> None:
    bench = moving_bench()
    bench.cmd(twist_payload(0.2))  # the default source drives (priority 50 outranks nav's 10)
    assert "outranked" in refused(bench, b'{"left": 1, "right": 1}')
    reason = refused(bench, b'{"left": 1, "right": 1, "source": "teleop"}')
    assert reason.startswith("a velocity command of default is in force: a position move starts from standstill")
    bench.cmd(twist_payload(0.0))
    assert ask(bench, 0.1, 0.1, source="default").accepted


def test_a_move_is_refused_when_the_speed_limit_is_below_the_robots_position_speed() -> None:
    bench = moving_bench()
    bench.conn.on_params_set(b'{"values": {"max_wheel_speed": 0.2}}', bench.t)
    reason = refused(bench, b'{"left": 1, "right": 1}')
    assert reason == "the robot runs position moves at 0.3 m/s, above the gateway's max_wheel_speed 0.2 m/s: refused"


# --------------------------------------------------------------------------- what ends a move


def started(bench: Bench, left: float = 2.0, right: float = 2.0, run: float = 1.0) -> WheelMoveReply:
    reply = ask(bench, left, right)
    assert reply.accepted
    bench.run(run)
    assert positions(bench)[-1].state is MoveState.RUNNING and bench.conn.move is not None
    return reply


def ended(bench: Bench) -> WheelPosition:
    """The move's last publication: it ended short; the robot is left standing and is sent no further position command."""
    last = positions(bench)[-1]
    assert last.state is MoveState.ENDED and last.reason and bench.conn.move is None
    at = bench.t
    bench.run(1.0)
    assert [r for _, r in sent(bench, at + 1e-9) if r.command is CommandCode.SET_LR_WHEEL_POSITION] == []
    assert bench.robot.speed_left == bench.robot.speed_right == 0.0 and bench.robot._position_left is None
    assert any(last.reason in reason for reason in errors(bench))  # reported on wheels/move as well
    return last


def test_an_estop_during_a_move_sends_emg_stop_and_ends_it() -> None:
    bench = moving_bench()
    started(bench)
    at = bench.t
    bench.conn.on_estop(*_estop(True), bench.t)
    bench.settle()
    assert [r.command for _, r in sent(bench, at)][:1] == [CommandCode.EMG_STOP]
    assert bench.robot.counters["emergency_stops"] == 1
    x = bench.robot.x
    assert ended(bench).reason == "the e-stop is engaged"
    assert bench.robot.x == x and x == pytest.approx(0.3, abs=0.02)


def test_the_emg_stop_waits_for_nothing_the_moves_end_is_told_once_the_bytes_are_taken() -> None:
    bench = moving_bench()
    started(bench)
    bench.conn.on_estop(*_estop(True), bench.t)
    assert b'"Command":1' in bench.conn.take_outgoing("control")
    assert not [e for e in bench.conn._events if isinstance(e, WheelPosition | ErrorReport)]  # nothing built before the write
    ends = [e for e in bench.conn.take_events() if isinstance(e, WheelPosition)]
    assert [(e.state, e.reason) for e in ends] == [(MoveState.ENDED, "the e-stop is engaged")]


def test_a_higher_source_that_speaks_ends_the_move_and_drives() -> None:
    bench = moving_bench()
    started(bench)
    at = bench.t
    bench.conn.on_cmd_vel("teleop", twist_payload(0.0, 0.5), bench.t)
    bench.settle()
    commands = [(r.command, r.left, r.right) for _, r in sent(bench, at)]
    assert commands[0] == (CommandCode.SET_LR_WHEEL_VELOCITY, 0.0, 0.0)  # the move is dropped on the robot first
    assert commands[1][0] is CommandCode.SET_LR_WHEEL_VELOCITY and commands[1][2] > 0  # then teleop's turn
    assert positions(bench)[-1].reason == "a velocity command of teleop replaces it"
    assert bench.robot.target_right > 0 and bench.robot._position_left is None


def test_a_higher_sources_zero_twist_ends_the_move_too() -> None:
    bench = moving_bench()
    started(bench)
    bench.cmd(twist_payload(0.0))  # default, priority 50
    assert ended(bench).reason == "a velocity command of default replaces it"


def test_the_moves_own_source_stops_it_with_a_zero_twist() -> None:
    bench = moving_bench()
    started(bench)
    bench.conn.on_cmd_vel("nav", twist_payload(0.0), bench.t)
    bench.settle()
    assert ended(bench).reason == "a velocity command of nav replaces it"


def test_a_lower_source_neither_drives_nor_ends_the_move() -> None:
    bench = moving_bench(source=["default:50", "nav:10", "wander:5:0.2"])
    reply = started(bench, 1.0, 1.0)
    for _ in range(10):
        bench.conn.on_cmd_vel("wander", twist_payload(0.5), bench.t)
        bench.run(0.2)
    bench.run(2.0)
    assert positions(bench)[-1].state is MoveState.DONE and positions(bench)[-1].move_id == reply.move_id
    assert [r.command for _, r in sent(bench, 0.5)] == [CommandCode.SET_LR_WHEEL_POSITION]


def test_a_lock_that_blocks_the_moves_source_ends_it() -> None:
    bench = moving_bench(lock=["dock:20"])
    started(bench)
    at = bench.t
    bench.conn.on_lock("dock", b'{"locked": true}', bench.t)
    bench.settle()
    assert [(r.command, r.left) for _, r in sent(bench, at)] == [(CommandCode.SET_LR_WHEEL_VELOCITY, 0.0)]
    assert ended(bench).reason == "a lock blocks nav"


def test_a_move_not_done_by_its_deadline_is_stopped_with_normal_stop() -> None:
    # the robot runs its moves at a third of the speed the gateway was told: it cannot be done in time
    bench = moving_bench(SimRobot(RobotParams(position_speed=0.1), now=0.0, seed=3))
    reply = ask(bench, 1.0, 1.0)
    bench.run(reply.deadline - 0.05)
    assert positions(bench)[-1].state is MoveState.RUNNING
    bench.run(0.1)
    assert reply.deadline == pytest.approx(1.0 / 0.3 * DEADLINE_FACTOR + DEADLINE_MARGIN_S, abs=0.01)
    stops = [CommandCode.SET_LR_WHEEL_VELOCITY, CommandCode.NORMAL_STOP]  # zero velocity, then NORMAL_STOP
    assert [r.command for _, r in sent(bench, 0.5)] == [CommandCode.SET_LR_WHEEL_POSITION, *stops]
    last = ended(bench)
    assert last.reason == f"not done by its deadline ({reply.deadline:.1f} s): stopped"
    assert bench.robot.x == pytest.approx(0.1 * reply.deadline, abs=0.02)


class IgnoresPositions(SimRobot):
    """A robot that answers SET_LR_WHEEL_POSITION and does nothing (one whose firmware lacks it)."""

    def handle(self, request: Request, now: float) -> list[bytes]:
        if request.command is CommandCode.SET_LR_WHEEL_POSITION:
            request = Request(CommandCode.EMPTY)
        return super().handle(request, now)


def test_wheels_that_do_not_turn_end_the_move_after_the_stall_time() -> None:
    bench = moving_bench(IgnoresPositions(RobotParams(), now=0.0, seed=3))
    reply = ask(bench, 1.0, 1.0)
    bench.run(STALL_S + 0.1)
    last = ended(bench)
    assert last.reason == f"the wheels stopped short of the target for {STALL_S:g} s: stopped"
    assert last.elapsed == pytest.approx(STALL_S, abs=0.1) and reply.accepted
    assert [r.command for _, r in sent(bench, 0.6)][-1] is CommandCode.NORMAL_STOP


class DropsPositions(SimRobot):
    """A robot that answers FULL_BUFFER to its first ``drops`` position commands (and drops them)."""

    def __init__(self, drops: float) -> None:
        super().__init__(RobotParams(), now=0.0, seed=3)
        self.drops = drops

    def handle(self, request: Request, now: float) -> list[bytes]:
        if request.command is CommandCode.SET_LR_WHEEL_POSITION and self.drops > 0:
            self.drops -= 1
            return [wire.encode_status(wire.STATUS_FULL_BUFFER)]
        return super().handle(request, now)


def test_a_dropped_position_command_is_sent_again_from_where_the_wheels_stand() -> None:
    bench = moving_bench(DropsPositions(2))
    ask(bench, 1.0, 1.0)
    bench.run(4.0)
    commands = [r for _, r in sent(bench, 0.5) if r.command is CommandCode.SET_LR_WHEEL_POSITION]
    assert len(commands) == 3 and {(r.left, r.right) for r in commands} == {(1013, 1054)}
    assert positions(bench)[-1].state is MoveState.DONE and bench.robot.x == pytest.approx(1.0, abs=0.002)


def test_a_robot_that_never_takes_the_command_ends_the_move() -> None:
    bench = moving_bench(DropsPositions(math.inf))
    ask(bench, 1.0, 1.0)
    bench.run(2.0)
    assert positions(bench)[-1].reason == "the robot did not take the position command 6 times: stopped"


def test_a_lost_link_ends_the_move() -> None:
    bench = moving_bench()
    started(bench)
    bench.conn.link_down("control", "closed by the robot", bench.t)
    bench.settle()
    last = positions(bench)[-1]
    assert last.state is MoveState.ENDED and last.reason == "control link down: closed by the robot"


def test_a_new_move_replaces_the_one_under_way() -> None:
    bench = moving_bench()
    first = started(bench)
    x = bench.robot.x
    second = ask(bench, -0.2, -0.2)
    assert second.accepted
    last_of_first = [p for p in positions(bench) if p.move_id == first.move_id][-1]
    assert last_of_first.state is MoveState.ENDED and last_of_first.reason == f"replaced by move {second.move_id}"
    bench.run(2.0)
    assert bench.robot.x == pytest.approx(x - 0.2, abs=0.01) and positions(bench)[-1].state is MoveState.DONE


def test_the_gateway_stopping_ends_the_move() -> None:
    bench = moving_bench()
    started(bench)
    bench.conn.stop_robot(bench.t)
    bench.settle()
    assert positions(bench)[-1].reason == "the gateway is stopping" and bench.robot.speed_left == 0.0
    assert refused(bench, b'{"left": 1, "right": 1}') == "the gateway is stopping: a position move is refused"
    assert [r.command for _, r in sent(bench, bench.t)] == [CommandCode.SET_LR_WHEEL_VELOCITY, CommandCode.NORMAL_STOP]


@pytest.mark.parametrize("seed", range(5))
def test_a_move_on_a_slow_robot_that_drops_commands_still_ends_at_its_target(seed: int) -> None:
    robot = SimRobot(RobotParams(), now=0.0, seed=seed)
    robot.faults = SimFaults(full_buffer=0.05, dropout=0.01, spike=0.005)
    bench = moving_bench(robot)
    bench.reply_delay = 0.012  # readings come a poll period late or so: a reading asked before a command tells nothing
    reply = ask(bench, 2.0, 2.0)
    bench.run(reply.deadline)
    last = positions(bench)[-1]
    assert last.state is MoveState.DONE, last.reason
    assert bench.robot.x == pytest.approx(2.0, abs=0.003) and abs(bench.robot.yaw) < 0.003
    assert last.elapsed < reply.expected + 0.5


def test_a_speed_limit_set_below_the_position_speed_ends_the_move() -> None:
    bench = moving_bench()
    started(bench)
    at = bench.t
    bench.conn.on_params_set(b'{"values": {"max_wheel_speed": 0.25}}', bench.t)
    bench.settle()
    assert [(r.command, r.left) for _, r in sent(bench, at)] == [(CommandCode.SET_LR_WHEEL_VELOCITY, 0.0)]
    assert ended(bench).reason == "max_wheel_speed was set below the robot's position speed"


def test_a_second_gateway_on_the_prefix_ends_the_move() -> None:
    bench = moving_bench()
    started(bench)
    mine = bench.conn.health(bench.t)
    other = GatewayHealth(stamp=mine.stamp, control=mine.control, log=mine.log, source="another-run")
    bench.conn.on_health_seen(encode(other), bench.t)
    bench.settle()
    assert "another gateway (run another-run) serves prefix robot" in ended(bench).reason
    assert "another gateway" in refused(bench, b'{"left": 1, "right": 1}')


def test_a_flood_of_moves_starts_one_a_tenth_of_a_second_at_most() -> None:
    bench = moving_bench()
    replies = []
    for _ in range(50):
        replies.append(ask(bench, 0.5, 0.5))
        bench.run(0.004)
    accepted = [r for r in replies if r.accepted]
    assert len(accepted) == 2  # 0.2 s of moves
    assert {r.reason for r in replies if not r.accepted} == {
        "moves come faster than one in 0.1 s: this one is refused, the one before goes on"
    }
    bench.run(2.0)
    assert positions(bench)[-1].state is MoveState.DONE and positions(bench)[-1].move_id == accepted[-1].move_id
    done = positions(bench)[-1]
    assert done.left - done.start_left == round(0.5 * 1012.536)  # the second ran whole, from where the first was cut
    assert bench.robot.x == pytest.approx(0.5 + done.start_left / 1012.536, abs=0.002)


def test_a_robot_whose_wheels_are_off_their_drawing_drives_straight_with_its_calibration() -> None:
    from blackmetal import robot_model as model

    def robot() -> SimRobot:
        return SimRobot(RobotParams.with_wheel_scales(left=1.015, right=0.99), now=0.0, seed=1)

    calibrated = moving_bench(
        robot(), impulses_left=model.IMPULSES_PER_METER_LEFT / 1.015, impulses_right=model.IMPULSES_PER_METER_RIGHT / 0.99
    )
    reply = ask(calibrated, 10.0, 10.0)
    calibrated.run(reply.deadline)
    assert positions(calibrated)[-1].state is MoveState.DONE and positions(calibrated)[-1].elapsed < reply.expected * 1.02
    assert calibrated.robot.x == pytest.approx(10.0, abs=0.005) and abs(math.degrees(calibrated.robot.yaw)) < 0.1
    nominal = moving_bench(robot())  # the firmware counts impulses: uncalibrated, the wheels' own errors curve the path
    nominal.run(ask(nominal, 1.0, 1.0).deadline)
    assert math.degrees(nominal.robot.yaw) == pytest.approx(-math.degrees(0.025 / 0.5), abs=0.1)


@pytest.mark.parametrize("poll_hz", [10.0, 50.0, 100.0])
def test_positions_are_read_within_the_poll_rate(poll_hz: float) -> None:
    bench = moving_bench(poll_hz=poll_hz)
    reply = ask(bench, 1.0, 1.0)
    bench.run(reply.deadline)
    published = positions(bench)
    assert published[-1].state is MoveState.DONE and bench.robot.x == pytest.approx(1.0, abs=0.002)
    rate = len(published) / published[-1].elapsed
    assert min(poll_hz, 25.0) * 0.9 <= rate <= min(poll_hz, 25.0) * 1.15  # one reading for every velocity poll at most
    assert published[-1].elapsed <= reply.expected + 3.0 / min(poll_hz, 25.0)  # done within a few readings
