"""The gateway process against a robot that misbehaves (tests/rogue_robot.py, not the simulator).

One test per way a robot, a network or a client can try to keep a stop from
landing; each asserts the stop lands, and in time.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh
from helpers import FLOODER, TRUE_ESTOPS, Child, client_config, free_port, wait_for
from rogue_robot import Behaviour, RogueRobot

from blackmetal.schemas import GatewayHealth, Keys, decode

pytestmark = pytest.mark.integration

KEYS = Keys()
EMG_STOP, VELOCITY, PREPARE, POLL = 1, 3, 7, 6


class Rig:
    def __init__(self, behaviour: Behaviour, *gateway_args: str) -> None:
        self.robot = RogueRobot(behaviour).start()
        self.zport = free_port()
        self.gateway = Child(
            ["-m", "blackmetal.gateway", "--control-port", str(self.robot.control_port), "--log-port", str(self.robot.log_port),
             "--no-multicast-scouting", "-l", f"tcp/127.0.0.1:{self.zport}", *gateway_args]
        )  # fmt: skip
        self.gateway.ready()
        self.session = zenoh.open(client_config(self.zport))
        self.errors: list[str] = []
        self.session.declare_subscriber(KEYS.errors, lambda s: self.errors.append(json.loads(s.payload.to_bytes())["reason"]))
        wait_for(lambda: self.robot.commands(POLL), what="the gateway to poll the robot")

    def close(self) -> None:
        self.session.close()
        self.gateway.stop()
        self.robot.stop()

    def put(self, key: str, payload: bytes) -> float:
        start = time.monotonic()
        self.session.put(key, payload)
        return start

    def health(self) -> GatewayHealth:
        for reply in self.session.get(KEYS.health, timeout=5):
            if reply.ok is not None:
                return decode(GatewayHealth, reply.ok.payload.to_bytes())
        raise AssertionError("no health")

    def drive(self, speed: float = 0.3) -> None:
        self.put(KEYS.cmd_vel, b'{"linear":{"x":%.3f}}' % speed)
        wait_for(lambda: self.robot.speed == (speed, speed), what=f"the robot at {speed} m/s")

    def estop_latency(self, payload: bytes = b'{"engaged": true}') -> float:
        """Seconds from the put on estop to EMG_STOP at the robot."""
        start = self.put(KEYS.estop, payload)
        (arrival, _), *_ = wait_for(lambda: self.robot.commands(EMG_STOP, since=start), what="EMG_STOP at the robot")
        return arrival - start

    def release(self) -> None:
        self.put(KEYS.estop_release, b'{"engaged": false}')
        wait_for(lambda: not self.health().estop, what="the release")

    def rss_mb(self) -> float:
        for line in Path(f"/proc/{self.gateway.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
        return float("nan")


@pytest.fixture
def rig_factory() -> Iterator[list[Rig]]:
    rigs: list[Rig] = []
    yield rigs
    for rig in rigs:
        rig.close()


def make(rigs: list[Rig], behaviour: Behaviour | None = None, *args: str) -> Rig:
    rig = Rig(behaviour or Behaviour(), *args)
    rigs.append(rig)
    return rig


def test_a_full_buffer_burst_at_the_brake_cannot_leave_the_robot_driving(rig_factory: list[Rig]) -> None:
    rig = make(rig_factory, Behaviour(full_buffer_on_stop=0.002), "--cmd-timeout", "0.5")
    rig.drive(0.5)
    last_put = time.monotonic()
    wait_for(lambda: not rig.robot.moving(), timeout=5, what="the brake to land")
    assert time.monotonic() - last_put < 1.5
    zeros = rig.robot.commands(VELOCITY, since=last_put)
    assert len(zeros) >= 2  # the first was dropped (FULL_BUFFER), a spaced re-send was taken
    assert all(w == (0.0, 0.0) for _, w in zeros)
    wait_for(lambda: rig.health().wheel_speeds == (0.0, 0.0), what="health to show the accepted zero")


@pytest.mark.parametrize(
    "payload",
    [*TRUE_ESTOPS, b"garbage"],
)
def test_every_shape_of_estop_stops_the_robot(rig_factory: list[Rig], payload: bytes) -> None:
    rig = make(rig_factory, Behaviour(), "--cmd-timeout", "0")
    rig.drive()
    assert rig.estop_latency(payload) < 1.0
    wait_for(lambda: not rig.robot.moving(), what="the robot to stop")
    assert rig.health().estop


def _brake_after_last_command(rig: Rig, during: Callable[[], None] = lambda: None) -> float:
    """Seconds from the last command to the command-timeout brake at the robot (``during`` runs right after it)."""
    rig.drive()  # 0.3 m/s, then no more commands: the brake is due 0.5 s after the last one
    last_put = rig.put(KEYS.cmd_vel, b'{"linear":{"x":0.3}}')
    during()
    wait_for(lambda: rig.robot.speed == (0.0, 0.0), timeout=10, what="the command-timeout brake")
    (brake_at, _), *_ = [c for c in rig.robot.commands(VELOCITY, since=last_put) if c[1] == (0.0, 0.0)]
    return brake_at - last_put


def _flood_case(rig: Rig, flood: Behaviour) -> dict[str, float]:
    """The flood's figures, and the same rig's without a flood just before it (a loaded machine is slower at both)."""
    baseline_brake = _brake_after_last_command(rig)
    baseline_estop = rig.estop_latency()
    rig.release()
    time.sleep(0.3)
    rss_before = rig.rss_mb()

    def start_flood() -> None:
        rig.robot.behaviour.log_flood, rig.robot.behaviour.control_flood = flood.log_flood, flood.control_flood

    brake = _brake_after_last_command(rig, start_flood)
    time.sleep(1.0)
    latencies = []
    for _ in range(3):
        latencies.append(rig.estop_latency())
        rig.release()
        time.sleep(0.3)
    rss_during = rig.rss_mb()
    rig.robot.behaviour.log_flood = rig.robot.behaviour.control_flood = b""
    ended = time.monotonic()

    def polling_again() -> bool:
        polls = [t for t, _ in rig.robot.commands(POLL, since=time.monotonic() - 0.5)]
        return len(polls) >= 20  # 50 Hz: 25 in half a second

    try:
        wait_for(polling_again, timeout=10, what="polling back at its rate")
    except AssertionError:
        raise AssertionError(f"polling did not come back: {rig.health()}\n{rig.errors[-5:]}") from None
    return {
        "estop_max_s": max(latencies),
        "estop_baseline_s": baseline_estop,
        "brake_s": brake,
        "brake_baseline_s": baseline_brake,
        "poll_recovery_s": time.monotonic() - ended,
        "rss_growth_mb": rss_during - rss_before,
    }


@pytest.mark.parametrize("port", ["log", "control"])
def test_a_flooding_robot_cannot_starve_the_stop_the_brake_or_the_polls(rig_factory: list[Rig], port: str) -> None:
    rig = make(rig_factory, Behaviour(), "--cmd-timeout", "0.5", "--log-silence-timeout", "30")
    flood = Behaviour(log_flood=b"{") if port == "log" else Behaviour(control_flood=b"{")
    figures = _flood_case(rig, flood)
    print(f"{port} flood: {figures}")
    # the flood costs the stop and the brake nothing they would not cost on this machine without it (the spec's 0.1 s
    # and 0.7 s on a quiet machine; a loaded one is slower with or without a flood: its own baseline, measured just before)
    assert figures["estop_max_s"] <= max(0.1, 3 * figures["estop_baseline_s"])
    assert figures["brake_s"] <= max(0.7, figures["brake_baseline_s"] + 0.2)
    assert figures["poll_recovery_s"] <= 2.0 + 0.5  # polling back within 2 s (0.5 s is this test's own window)
    assert figures["rss_growth_mb"] < 20


def test_valid_log_reports_at_full_speed_do_not_slow_the_polls(rig_factory: list[Rig]) -> None:
    rig = make(rig_factory, Behaviour(), "--cmd-timeout", "0")

    def polls_in(seconds: float) -> int:
        start = time.monotonic()
        time.sleep(seconds)
        return len([t for t, _ in rig.robot.commands(POLL, since=start) if t < start + seconds])

    time.sleep(1.0)
    baseline, baseline_estop = polls_in(2.0), rig.estop_latency()  # this machine, now, without the flood
    rig.release()
    rig.robot.behaviour.log_flood = b'{"state":1,"direction":1}'
    time.sleep(1.0)
    flooded = polls_in(2.0)
    print(f"polls in 2 s: {baseline} before the flood, {flooded} during it (50 Hz asked: 100)")
    assert flooded >= 0.7 * baseline  # the flood took 75 % of them before the fix (13 Hz of 50)
    assert rig.estop_latency() <= max(0.1, 3 * baseline_estop)


def test_a_cmd_vel_flood_cannot_delay_the_estop_or_grow_memory(rig_factory: list[Rig]) -> None:
    rig = make(rig_factory, Behaviour(), "--cmd-timeout", "0")
    rig.drive(0.1)
    rss_before = rig.rss_mb()
    flooders = [
        subprocess.Popen([sys.executable, "-c", FLOODER, str(rig.zport), KEYS.cmd_vel, "8", str(n)]) for n in range(3)
    ]  # three publishers at full speed, each its own process
    try:
        time.sleep(2.0)
        latencies = []
        for _ in range(5):
            latencies.append(rig.estop_latency())
            time.sleep(0.2)
            rig.release()
            time.sleep(0.2)
        rss_after = rig.rss_mb()
    finally:
        for flooder in flooders:
            flooder.kill()
            flooder.wait(5)
    print(f"e-stop under a cmd_vel flood: {[round(x * 1000, 1) for x in latencies]} ms; RSS {rss_before:.1f} -> {rss_after:.1f} MB")
    assert statistics.median(latencies) <= 0.1  # the target; measured alone: 35-56 ms
    assert max(latencies) <= 0.25  # three flooders saturate both cores of the machine, so allow scheduling noise
    assert rss_after - rss_before < 15
    # the publisher is told, on errors: the flood and what it costs, then its end
    assert any(f"on {KEYS.cmd_vel}: a publisher floods it" in e for e in rig.errors), rig.errors
    wait_for(lambda: any(f"the flood on {KEYS.cmd_vel} is over" in e for e in rig.errors), timeout=20, what="the flood's end reported")


def test_late_replies_are_paired_honestly_and_reported(rig_factory: list[Rig]) -> None:
    rig = make(rig_factory, Behaviour(), "--cmd-timeout", "0", "--silence-timeout", "5")
    rig.robot.behaviour.reply_delay = 0.7
    wait_for(lambda: (h := rig.health()).last_rtt_ms is not None and h.last_rtt_ms > 600, what="the true round trip in health")
    assert rig.health().last_rtt_ms == pytest.approx(700, abs=60)
    wait_for(lambda: any("robot slow" in e for e in rig.errors), what="a slow-robot report")
    assert rig.health().control.state == "connected"


def test_emg_stop_and_prepare_are_spaced_when_the_robot_is_always_full(rig_factory: list[Rig]) -> None:
    rig = make(rig_factory, Behaviour(always_full=True), "--cmd-timeout", "0")
    start = rig.put(KEYS.estop, b'{"engaged": true}')
    time.sleep(3.0)
    emg = rig.robot.commands(EMG_STOP, since=start)
    prepare = rig.robot.commands(PREPARE, since=start)
    assert 3 <= len(emg) <= 3 * 50  # was 5,435 per second
    assert len(prepare) <= 3 * 50  # was 19,416 in 3 s
    rig.robot.behaviour.always_full = False
    wait_for(lambda: rig.robot.commands(EMG_STOP, since=time.monotonic() - 1.0), what="EMG_STOP taken once the robot recovers")


def test_a_robot_that_closes_every_connection_gets_a_backoff_not_a_storm() -> None:
    robot = RogueRobot(Behaviour(close_at_once=True)).start()
    gateway = Child(["-m", "blackmetal.gateway", "--control-port", str(robot.control_port), "--log-port", str(robot.log_port),
                     "--no-multicast-scouting", "-l", f"tcp/127.0.0.1:{free_port()}"])  # fmt: skip
    try:
        gateway.ready()
        before = robot.connections
        time.sleep(6.0)
        # backoff 0.05, 0.1, 0.2, 0.4, 0.8, 1.6, 2, 2 s: 8 attempts in the first 6 s (was 144-149 in 10 s)
        assert robot.connections - before <= 9
    finally:
        gateway.stop()
        robot.stop()


def test_losing_the_log_link_is_reported_on_errors(rig_factory: list[Rig]) -> None:
    rig = make(rig_factory, Behaviour(), "--log-silence-timeout", "1.0")
    rig.robot.behaviour.log_silent = True
    wait_for(lambda: any("log link down" in e for e in rig.errors), what="the log link loss on errors")
    rig.robot.behaviour.log_silent = False
    wait_for(lambda: any("log link up again" in e for e in rig.errors), what="the log link's recovery on errors")


def test_stop_robot_stops_a_robot_whose_gateway_is_gone() -> None:
    robot = RogueRobot(Behaviour()).start()
    try:
        robot.speed = (0.4, 0.4)
        robot.behaviour.full_buffer_until = time.monotonic() + 0.05  # it is busy at first
        result = subprocess.run(
            [sys.executable, "-m", "blackmetal", "stop-robot", "--robot", "127.0.0.1", "--control-port", str(robot.control_port)],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert result.returncode == 0, result.stderr
        assert robot.speed == (0.0, 0.0) and robot.commands(2)  # zero velocity, then NORMAL_STOP
    finally:
        robot.stop()
    unreachable = subprocess.run(
        [sys.executable, "-m", "blackmetal", "stop-robot", "--control-port", str(free_port()), "--timeout", "1"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert unreachable.returncode == 1 and unreachable.stderr.count("\n") == 1 and "cannot connect" in unreachable.stderr


def test_up_stops_the_robot_when_its_gateway_is_killed() -> None:
    """kill -9 of the gateway under ``blackmetal up``: the simulated robot stops within a fraction of a second."""
    zport = free_port()
    up = Child(["-m", "blackmetal", "up", "-l", f"tcp/127.0.0.1:{zport}", "--no-multicast-scouting"])
    try:
        info = up.ready(timeout=60)
        with zenoh.open(client_config(zport)) as session:
            truth: list[tuple[float, float, float]] = []
            session.declare_subscriber(
                KEYS.sim_truth, lambda s: truth.append((time.monotonic(), *(lambda p: (p["x"], p["v"]))(json.loads(s.payload.to_bytes()))))
            )
            for _ in range(15):
                session.put(KEYS.cmd_vel, b'{"linear":{"x":0.4}}')
                time.sleep(0.1)
            wait_for(lambda: truth and truth[-1][2] == pytest.approx(0.4), what="0.4 m/s")
            killed_at = time.monotonic()
            import os
            import signal

            os.kill(info["children"]["gateway"], signal.SIGKILL)
            wait_for(lambda: truth and truth[-1][0] > killed_at and truth[-1][2] == 0.0, timeout=10, what="the robot to stop")
            x_at_kill = statistics.median(x for t, x, _ in truth if abs(t - killed_at) < 0.03)
            stopped = next(t for t, _, v in truth if t > killed_at and v == 0.0)
            travel = truth[-1][1] - x_at_kill
            print(f"after kill -9 of the gateway: stopped in {stopped - killed_at:.3f} s, travelled {travel * 1000:.0f} mm")
            assert stopped - killed_at < 1.0 and travel < 0.4  # was the robot's own 10 s watchdog: 4 m at 0.4 m/s
        up.wait_line(r"gateway started again \(pid \d+\)")  # as systemd's Restart=on-failure does
        assert "gateway gone; the robot was sent zero velocity and NORMAL_STOP" in up.output()
    finally:
        up.stop()
