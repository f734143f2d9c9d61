"""The gateway's sans-I/O robot connection on a fake clock: no sockets, no loop, no sleeping.

The robot on the other side is the simulator's pure physics (``SimRobot``)
on the same fake clock: every request the connection writes is decoded and
handled, every reply fed back. Scenarios that used to need seconds of real
time (keep-alive past the 10 s watchdog, the command-timeout brake,
FULL_BUFFER retries, reconnects, a silent robot) run in milliseconds.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import pytest
from helpers import MemoryLatchStore

from blackmetal import wire
from blackmetal.gateway.core import GatewayCore
from blackmetal.gateway.estop import read_estop
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.schemas import ErrorReport, GatewayHealth, RobotStatus, SimFaults, WheelImpulses
from blackmetal.sim.physics import RobotParams, SimRobot
from blackmetal.wire import CommandCode, Request

WALL0 = 1_800_000_000.0


class Bench:
    """A GatewayCore wired to a SimRobot through a fake clock."""

    def __init__(self, robot: SimRobot | None = None, **settings: Any) -> None:
        self.t = 0.0
        config = GatewaySettings(**settings)
        config.check()
        self.robot = robot or SimRobot(RobotParams(), now=0.0, seed=3)
        self.conn = GatewayCore(config, 0.0, wallclock=lambda: WALL0 + self.t)
        self.latch = MemoryLatchStore()
        self.decoder = wire.RequestDecoder()
        self.requests: list[tuple[float, Request]] = []
        self.events: list[Any] = []
        self.answering = True
        #: Replies reach the gateway this long after the request (a slow robot).
        self.reply_delay = 0.0
        self._in_transit: list[tuple[float, bytes]] = []
        #: Until this time the robot answers every command FULL_BUFFER (and drops it).
        self.full_buffer_until = -math.inf

    def connect(self) -> None:
        self.conn.link_up("control", self.t)
        self.conn.link_up("log", self.t)
        self.settle()

    def settle(self) -> None:
        """Deliver what the connection wrote; feed the robot's replies back, until quiet."""
        for _ in range(100):
            data = self.conn.take_outgoing("control")
            if not data:  # as the host does once the bytes are written: save a change of the e-stop latch
                latch = self.conn.take_latch()
                if latch is None:
                    break
                self.conn.latch_saved(latch, self.latch.save(latch), self.t)
                continue
            replies = b""
            for request in self.decoder.feed(data):
                assert isinstance(request, Request), request
                self.requests.append((self.t, request))
                if self.answering and self.t < self.full_buffer_until:
                    replies += wire.encode_status(wire.STATUS_FULL_BUFFER)
                elif self.answering:
                    replies += b"".join(self.robot.handle(request, self.t))
            if replies and self.reply_delay > 0:
                self._in_transit.append((self.t + self.reply_delay, replies))
            elif replies:
                self.conn.receive("control", replies, self.t)
        self.events += self.conn.take_events()

    def run(self, seconds: float) -> None:
        """Advance the fake clock, running every deadline on the way; the log port reports once a second."""
        end = self.t + seconds
        steps = 0
        next_log = math.floor(self.t) + 1.0
        while True:
            arrival = self._in_transit[0][0] if self._in_transit else math.inf
            deadline = min(self.conn.next_deadline(), next_log, arrival)
            if deadline > end:
                break
            self.t = max(self.t, deadline)
            while self._in_transit and self._in_transit[0][0] <= self.t:
                self.conn.receive("control", self._in_transit.pop(0)[1], self.t)
            if self.t >= next_log:
                next_log += 1.0
                if self.answering and self.conn.links["log"].connected:
                    self.conn.receive("log", wire.encode_log_report(1, 1), self.t)
            self.conn.tick(self.t)
            self.settle()
            steps += 1
            assert steps < 100_000, "the connection's deadline does not advance"
        self.t = end
        self.conn.tick(self.t)
        self.settle()

    def cmd(self, payload: bytes) -> None:
        """Put ``payload`` on cmd_vel, then let 5 ms pass (commands are spaced by the 500/s cap)."""
        self.conn.on_cmd_vel("default", payload, self.t)
        self.settle()
        self.run(0.005)

    def velocity(self) -> list[tuple[float, float, float]]:
        """(time, left, right) of every velocity command the robot received."""
        return [(t, r.left, r.right) for t, r in self.requests if r.command is CommandCode.SET_LR_WHEEL_VELOCITY]  # type: ignore[misc]

    def count(self, code: CommandCode) -> int:
        return sum(1 for _, r in self.requests if r.command is code)

    def of(self, kind: type) -> list[Any]:
        return [e for e in self.events if isinstance(e, kind)]


def twist_payload(v: float, w: float = 0.0) -> bytes:
    return f'{{"linear":{{"x":{v}}},"angular":{{"z":{w}}}}}'.encode()


def test_link_up_prepares_stands_still_and_polls_at_the_rate() -> None:
    bench = Bench(poll_hz=50.0)
    bench.connect()
    codes = [r.command for _, r in bench.requests[:2]]
    assert codes == [CommandCode.PREPARE_WHEEL_CONTROLLER, CommandCode.SET_LR_WHEEL_VELOCITY]
    assert bench.velocity()[0][1:] == (0.0, 0.0)  # never an old motion
    bench.run(2.0)
    impulses = bench.of(WheelImpulses)
    assert 99 <= len(impulses) <= 101  # 50 Hz for 2 s
    assert [m.seq for m in impulses] == list(range(len(impulses)))
    assert bench.of(RobotStatus) and bench.of(RobotStatus)[0].state_name == "READY"
    health = bench.of(GatewayHealth)[-1]
    assert health.control.state == "connected" and health.poll_hz == pytest.approx(50.0, rel=0.02)


def test_a_left_arc_reaches_the_robot_as_wheel_speeds() -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.2},"angular":{"z":0.4}}')
    assert bench.velocity()[-1][1:] == pytest.approx((0.1, 0.3))  # (left, right): right faster, a left turn
    bench.run(1.0)
    impulses = bench.of(WheelImpulses)[-1]
    assert impulses.left > 0 and impulses.right < 0  # the right encoder is mirrored


def test_command_timeout_brakes_exactly_at_the_timeout() -> None:
    bench = Bench(cmd_timeout=0.5, poll_hz=10.0)
    bench.connect()
    bench.run(0.05)
    sent_at = bench.t
    bench.cmd(b'{"linear":{"x":0.2}}')
    bench.run(2.0)
    t_brake, left, right = bench.velocity()[-1]
    assert (left, right) == (0.0, 0.0)
    assert 0.5 <= t_brake - sent_at <= 0.501  # on its own deadline, not at the next poll
    assert bench.conn.health(bench.t).cmd_timeout_active


def test_keepalive_carries_a_long_run_past_the_robot_watchdog() -> None:
    bench = Bench(cmd_timeout=0.0, keepalive=5.0)
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.1}}')
    bench.run(25.0)
    bench.robot.advance(bench.t)
    assert bench.robot.moving and bench.robot.counters["watchdog_stops"] == 0
    assert bench.conn.counters.keepalives == 5
    times = [t for t, left, _ in bench.velocity() if left == 0.1]
    assert all(4.99 <= b - a <= 5.01 for a, b in itertools.pairwise(times))


def test_without_keepalive_the_robot_watchdog_would_stop_it() -> None:
    """The counterpart of the test above: the watchdog is real, so the keep-alive is what keeps it going."""
    robot = SimRobot(RobotParams(), now=0.0, seed=3)
    robot.handle(wire.set_velocity(left=0.1, right=0.1), 0.0)
    robot.advance(10.5)
    assert not robot.moving and robot.counters["watchdog_stops"] == 1


def test_full_buffer_is_retried_until_accepted() -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.robot.faults = SimFaults(full_buffer=0.5)
    for speed in (0.1, 0.2, 0.3, 0.25, 0.15):
        bench.cmd(b'{"linear":{"x":%.2f}}' % speed)
        bench.run(0.2)
        assert bench.robot.target_left == pytest.approx(speed)
    assert bench.conn.counters.full_buffer > 0 and bench.conn.counters.full_buffer_retries > 0


def test_estop_goes_out_first_latches_and_releases() -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.2}}')
    bench.conn.on_estop(read_estop(b'{"engaged": true}'), bench.t)
    bench.settle()
    assert bench.requests[-1][1].command is CommandCode.EMG_STOP  # at once, ahead of the next poll
    assert not bench.robot.moving and bench.robot.counters["emergency_stops"] == 1
    bench.cmd(b'{"linear":{"x":0.2}}')
    assert any("emergency stop" in e.reason for e in bench.of(ErrorReport))
    assert not bench.robot.moving
    bench.conn.on_estop(read_estop(b'{"engaged": false}', release_key=True), bench.t)
    bench.settle()
    bench.cmd(b'{"linear":{"x":0.15}}')
    assert bench.robot.target_left == pytest.approx(0.15)


def test_reconnect_prepares_again_and_never_resumes_old_motion() -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.2}}')
    bench.run(0.5)
    bench.conn.link_down("control", "closed by the robot", bench.t)
    bench.cmd(b'{"linear":{"x":0.3}}')  # refused while down, not queued
    assert any("link is down" in e.reason for e in bench.of(ErrorReport))
    bench.run(0.2)
    bench.conn.link_up("control", bench.t)
    bench.settle()
    assert bench.count(CommandCode.PREPARE_WHEEL_CONTROLLER) == 2
    bench.run(1.0)
    assert bench.velocity()[-1][1:] == (0.0, 0.0)
    assert all(left != 0.3 for _, left, _ in bench.velocity())
    assert bench.conn.health(bench.t).control.reconnects == 1


def test_requests_unanswered_past_the_reply_timeout_are_given_up_without_a_backlog() -> None:
    bench = Bench(reply_timeout=0.2, silence_timeout=5.0, poll_hz=20.0)
    bench.connect()
    bench.answering = False
    bench.run(3.0)
    assert bench.conn.counters.lost_replies >= 3
    assert bench.conn.counters.polls_skipped > 0
    assert len(bench.conn.exchange.outstanding) <= 2  # never a backlog


def test_late_replies_are_paired_with_their_own_requests() -> None:
    """A robot answering 0.7 s late (reply timeout 0.5 s): nothing is attributed to a later request."""
    bench = Bench(reply_timeout=0.5, silence_timeout=5.0, poll_hz=50.0, cmd_timeout=0.0)
    bench.connect()
    bench.run(0.5)
    bench.reply_delay = 0.7
    bench.cmd(b'{"linear":{"x":0.2}}')
    bench.run(6.0)
    health = bench.conn.health(bench.t)
    assert health.last_rtt_ms == pytest.approx(700.0, abs=1.0)  # the true round trip
    assert any("robot slow" in e.reason and "700 ms" in e.reason for e in bench.of(ErrorReport))
    assert health.wheel_speeds == pytest.approx((0.2, 0.2))  # what the robot accepted, late but accepted
    assert 1.0 <= health.poll_hz <= 1.6  # polling waits for the slow robot instead of piling up
    late = bench.of(WheelImpulses)[-3:]
    assert all(m.left in (202, 203) for m in late)  # readings of a moving robot, not of the old standstill
    assert len(bench.conn.exchange.outstanding) <= 3


def test_malformed_replies_are_counted_and_reported_not_fatal() -> None:
    bench = Bench()
    bench.connect()
    bench.conn.receive("control", b"\x00\xffgarbage{no}{", bench.t)
    bench.run(0.5)
    assert bench.conn.counters.malformed_replies >= 1
    assert any("malformed reply" in e.reason for e in bench.of(ErrorReport))
    assert len(bench.of(WheelImpulses)) >= 20


def test_hostile_cmd_vel_is_rejected_and_never_reaches_the_robot() -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.1}}')
    for payload in (b"", b"nan", b'{"linear":{"x":NaN}}', b'{"linear":{"x":1e308}}', b'{"linear":{"x":"1"}}', b"{" * 70000):
        bench.cmd(payload)
    assert bench.conn.counters.rejected_inputs == 6
    assert bench.velocity()[-1][1:] == pytest.approx((0.1, 0.1))
    assert all(abs(left) <= 0.8 and abs(right) <= 0.8 for _, left, right in bench.velocity())


def test_shutdown_leaves_the_robot_standing() -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.2}}')
    bench.conn.stop_robot(bench.t)
    bench.settle()
    assert bench.velocity()[-1][1:] == (0.0, 0.0)
    assert bench.count(CommandCode.NORMAL_STOP) == 1 and bench.conn.idle


# ----------------------------------------------------------------------------- failing safe (issue: fail safe under robot faults)


def test_a_short_full_buffer_burst_cannot_lose_the_brake() -> None:
    """0.5 m/s, the publisher stops, the timeout brake meets 2 ms of FULL_BUFFER: the zero is re-sent until taken."""
    bench = Bench(cmd_timeout=0.5)
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.5}}')
    last_cmd = bench.conn.governor.last_cmd_at  # the timeout counts from the command's arrival
    bench.run(last_cmd + 0.5 - 0.0005 - bench.t)
    bench.full_buffer_until = bench.t + 0.002  # the brake falls inside this burst
    bench.run(1.0)
    bench.robot.advance(bench.t)
    assert bench.robot.target_left == 0.0 and not bench.robot.moving
    zeros = [t for t, left, _ in bench.velocity() if left == 0.0 and t > last_cmd]
    assert len(zeros) >= 2 and zeros[1] - zeros[0] >= 0.005  # re-sent, spaced
    assert bench.conn.health(bench.t).wheel_speeds == (0.0, 0.0)  # what the robot accepted


def test_health_reports_what_the_robot_accepted_not_what_was_sent() -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.3}}')
    bench.full_buffer_until = math.inf
    bench.cmd(b'{"linear":{"x":0.1}}')
    bench.run(0.5)
    assert bench.conn.health(bench.t).wheel_speeds == pytest.approx((0.3, 0.3))


def test_an_operators_zero_is_confirmed_like_the_brake() -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.4}}')
    bench.full_buffer_until = bench.t + 0.05
    bench.cmd(b'{"linear":{"x":0.0}}')
    bench.run(2.0)
    bench.robot.advance(bench.t)
    assert not bench.robot.moving and bench.conn.health(bench.t).wheel_speeds == (0.0, 0.0)


def test_emg_stop_and_prepare_retries_stay_under_50_a_second() -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.full_buffer_until = math.inf
    bench.connect()
    bench.conn.on_estop(read_estop(b'{"engaged": true}'), bench.t)
    bench.run(3.0)
    assert 3 <= bench.count(CommandCode.EMG_STOP) <= 3 * 50
    assert 3 <= bench.count(CommandCode.PREPARE_WHEEL_CONTROLLER) <= 3 * 50
    bench.full_buffer_until = bench.t  # the robot recovers: the stop lands
    bench.run(1.0)
    assert bench.robot.counters["emergency_stops"] >= 1


def test_health_says_what_the_robot_was_last_sent() -> None:
    bench = Bench()
    bench.connect()
    assert bench.conn.health(bench.t).last_sent == "velocity 0.000 0.000"  # the zero velocity after connecting
    bench.conn.on_cmd_vel("default", twist_payload(0.2), bench.t)
    bench.run(0.05)
    assert bench.conn.health(bench.t).last_sent == "velocity 0.200 0.200"
    bench.conn.on_estop(read_estop(b'{"engaged": true}'), bench.t)
    health = bench.conn.health(bench.t)
    assert health.estop and health.last_sent == "EMG_STOP" and health.last_sent_stamp is not None


@pytest.mark.parametrize(("delay", "least_hz"), [(0.005, 49.0), (0.025, 39.0), (0.021, 47.0)])
def test_a_reading_that_comes_after_the_next_poll_was_due_delays_that_poll_and_never_queues_it(delay: float, least_hz: float) -> None:
    """Replies ``delay`` after each request at 50 Hz: a poll due while the one before is unanswered goes out as soon
    as that one's reading comes (a loaded loop that reads a reply late is the same case), one in flight at most."""
    bench = Bench(poll_hz=50.0, cmd_timeout=0.0)
    bench.connect()
    bench.reply_delay = delay
    bench.run(0.5)
    start = bench.t
    bench.run(4.0)
    polls = [t for t, r in bench.requests if r.command is CommandCode.GET_LR_WHEEL_VELOCITY and t >= start]
    assert len(polls) / 4.0 >= least_hz  # before: a reply 1 ms after the next grid instant halved the rate to 25 Hz
    assert len(polls) / 4.0 <= 50.5  # never faster than asked
    assert min(b - a for a, b in itertools.pairwise(polls)) >= min(delay, 0.02) - 1e-9  # one in flight at most
    assert bench.conn.counters.replies > 0 and bench.conn.counters.lost_replies == 0
