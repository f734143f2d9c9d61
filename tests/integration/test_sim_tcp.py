"""``blackmetal sim`` as a real process: TCP control and log ports, Zenoh truth, faults, shutdown."""

from __future__ import annotations

import json
import socket
import time

import pytest
import zenoh
from helpers import TIMEOUT, Child, SimProcess, client_config, free_port, wait_for, zenoh_listen_args

from blackmetal import wire
from blackmetal.schemas import Pose, SimFaults, decode
from blackmetal.wire import CommandCode, LogReport, Malformed, ReplyDecoder, SpeedReading, StatusReply

pytestmark = pytest.mark.integration


class RobotClient:
    """A minimal blocking client of the control port, built on the sans-I/O codec."""

    def __init__(self, host: str, port: int) -> None:
        self.sock = socket.create_connection((host, port), timeout=TIMEOUT)
        self.decoder = ReplyDecoder()
        self.pending: list[object] = []
        self.malformed = 0

    def next_reply(self) -> object:
        while not self.pending:
            data = self.sock.recv(4096)
            if not data:
                raise ConnectionError("robot closed the connection")
            for item in self.decoder.feed(data):
                if isinstance(item, Malformed):
                    self.malformed += 1
                else:
                    self.pending.append(item)
        return self.pending.pop(0)

    def request(self, request: wire.Request) -> list[object]:
        self.sock.sendall(wire.encode_request(request))
        status = self.next_reply()
        assert isinstance(status, StatusReply)
        if status.ok and request.command in wire.DATA_COMMANDS:
            return [status, self.next_reply()]
        return [status]

    def speeds(self) -> SpeedReading:
        replies = self.request(wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY))
        assert isinstance(replies[-1], SpeedReading), replies
        return replies[-1]

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def sim(children: list[Child]) -> tuple[SimProcess, int]:
    zport = free_port()
    proc = SimProcess("--watchdog", "1.5", "--seed", "7", "--log-interval", "0.2", *zenoh_listen_args(zport))
    children.append(proc)
    return proc, zport


def test_drive_poll_and_watch_the_truth_move(sim: tuple[SimProcess, int]) -> None:
    proc, zport = sim
    with zenoh.open(client_config(zport)) as session:
        truths: list[Pose] = []
        sub = session.declare_subscriber("robot/sim/truth", lambda s: truths.append(decode(Pose, s.payload.to_bytes())))
        wait_for(lambda: len(truths) > 5, what="truth samples")
        client = RobotClient(proc.host, proc.control_port)
        assert client.request(wire.simple(CommandCode.PREPARE_WHEEL_CONTROLLER)) == [StatusReply("RECIEVE_OK")]
        assert client.speeds() == SpeedReading(left=0, right=0)
        # a left turn: right wheel faster
        assert client.request(wire.set_velocity(left=0.2, right=0.3)) == [StatusReply("RECIEVE_OK")]
        client.speeds()  # a reading is the mean rate since the previous one: this one is partial
        time.sleep(0.02)
        speeds = client.speeds()
        assert speeds.left in (202, 203) and speeds.right in (-317, -316)
        wait_for(lambda: truths[-1].x > 0.05 and truths[-1].y > 0.0 and truths[-1].yaw > 0.0, what="a left turn")
        # truth arrives at >= 50 Hz
        n0, t0 = len(truths), time.monotonic()
        time.sleep(1.0)
        rate = (len(truths) - n0) / (time.monotonic() - t0)
        assert rate >= 40, rate  # 50 Hz nominal; slack for a loaded machine
        # the watchdog (1.5 s here) stops the robot when commands stop, polls do not count
        deadline = time.monotonic() + TIMEOUT
        while time.monotonic() < deadline and client.speeds() != SpeedReading(left=0, right=0):
            time.sleep(0.1)
        assert client.speeds() == SpeedReading(left=0, right=0)
        x = truths[-1].x
        time.sleep(0.3)
        assert truths[-1].x == pytest.approx(x, abs=1e-9)
        replies = list(session.get("robot/sim/truth", timeout=5))
        assert decode(Pose, replies[0].ok.payload.to_bytes()).x == pytest.approx(x, abs=1e-9)
        sub.undeclare()
        client.close()


def test_log_port_reports_ready_north(sim: tuple[SimProcess, int]) -> None:
    proc, _ = sim
    with socket.create_connection((proc.host, proc.log_port), timeout=TIMEOUT) as sock:
        decoder = ReplyDecoder()
        reports: list[object] = []
        while len(reports) < 2:
            reports.extend(decoder.feed(sock.recv(1024)))
        assert reports[:2] == [LogReport(1, 1), LogReport(1, 1)]


def test_faults_set_at_run_time_over_zenoh(sim: tuple[SimProcess, int]) -> None:
    proc, zport = sim
    client = RobotClient(proc.host, proc.control_port)
    with zenoh.open(client_config(zport)) as session:
        state: dict[str, object] = {}

        def set_faults(**faults: object) -> None:
            """Partial update: fields not named keep their value."""
            state.update(faults)
            wanted = SimFaults(**state)  # type: ignore[arg-type]

            def applied() -> bool:
                # re-put until applied: a put made before routes are known reaches nobody
                session.put("robot/sim/faults", json.dumps(faults))
                replies = list(session.get("robot/sim/faults", timeout=5))
                return bool(replies) and replies[0].ok is not None and decode(SimFaults, replies[0].ok.payload.to_bytes()) == wanted

            wait_for(applied, interval=0.2, what=f"faults {faults}")

        set_faults(full_buffer=1.0)
        assert client.request(wire.set_velocity(left=0.1, right=0.1)) == [StatusReply("FULL_BUFFER")]
        set_faults(full_buffer=0.0, garbage=1.0, split=1.0, glue=0.5)
        client.request(wire.set_velocity(left=0.1, right=0.1))
        client.speeds()  # partial interval
        for _ in range(30):
            client.request(wire.set_velocity(left=0.1, right=0.1))  # feed the 1.5 s watchdog: the speed stays constant
            assert client.speeds().left in (101, 102)
        assert client.malformed > 0  # garbage was seen, skipped, and every reply still arrived
        set_faults(garbage=0.0, split=0.0, glue=0.0, delay=0.3)
        start = time.monotonic()
        client.speeds()
        assert time.monotonic() - start >= 0.25
        # a hostile fault setting is refused and reported, nothing changes
        errors: list[bytes] = []
        sub = session.declare_subscriber("robot/errors", lambda s: errors.append(s.payload.to_bytes()))
        time.sleep(0.2)
        session.put("robot/sim/faults", b'{"dropout": 7}')
        wait_for(lambda: errors, what="an error report")
        assert b"dropout" in errors[0]
        sub.undeclare()
        set_faults(disconnect=1.0)
        with pytest.raises(ConnectionError):
            client.speeds()
        set_faults(disconnect=0.0, delay=0.0)
    client.close()
    # the robot accepts a new client after a disconnect; the reading is the mean rate since the
    # previous one, so on a slow machine the robot's 10 s watchdog may have stopped it on the way
    again = RobotClient(proc.host, proc.control_port)
    reading = again.speeds()
    assert 0 <= reading.left <= 102 and 0 <= -reading.right <= 106  # 0.1 m/s is 101-102 | 105-106 impulses/s
    again.close()


def test_a_new_control_client_takes_over(sim: tuple[SimProcess, int]) -> None:
    proc, _ = sim
    first = RobotClient(proc.host, proc.control_port)
    first.speeds()
    second = RobotClient(proc.host, proc.control_port)
    assert second.speeds() == SpeedReading(left=0, right=0)
    with pytest.raises((ConnectionError, OSError)):
        first.speeds()
    second.close()
    first.close()


def test_sigint_and_sigterm_stop_it_within_two_seconds(children: list[Child]) -> None:
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM):
        zport = free_port()
        proc = SimProcess(*zenoh_listen_args(zport))
        children.append(proc)
        client = RobotClient(proc.host, proc.control_port)  # an open client must not hold it up
        client.speeds()
        start = time.monotonic()
        assert proc.stop(sig) == 0
        assert time.monotonic() - start < 2.0
        client.close()


def test_plain_sim_needs_no_zenoh(children: list[Child]) -> None:
    proc = SimProcess()
    children.append(proc)
    client = RobotClient(proc.host, proc.control_port)
    client.request(wire.set_velocity(left=0.2, right=0.2))
    client.speeds()  # partial interval
    time.sleep(0.02)
    assert client.speeds().left in (202, 203)
    client.close()
    assert "truth on" not in proc.output()


def test_bad_flags_are_a_clear_error(children: list[Child]) -> None:
    proc = Child(["-m", "blackmetal", "sim", "--dropout", "2"])
    children.append(proc)
    assert proc.proc.wait(TIMEOUT) == 2
    proc.stop()
    assert "dropout" in proc.output() and "Traceback" not in proc.output()
