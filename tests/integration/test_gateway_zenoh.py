"""The gateway as a real process on Zenoh, against ``blackmetal sim`` on loopback."""

from __future__ import annotations

import json
import signal
import time

import pytest
import zenoh
from helpers import Child, SimProcess, client_config, free_port, wait_for, zenoh_connect_args

from blackmetal.schemas import GatewayHealth, Pose, WheelImpulses, decode

pytestmark = pytest.mark.integration


class Rig:
    """A Zenoh router (the hub: nobody under test), gateway and sim as its clients, and a client session."""

    def __init__(self, children: list[Child], *gateway_args: str, sim_ports: tuple[int, int] | None = None) -> None:
        self.zport = free_port()
        self.children = children
        self.sim_ports = sim_ports or (free_port(), free_port())
        router = Child(["-m", "blackmetal", "router", "-l", f"tcp/127.0.0.1:{self.zport}"])
        children.append(router)
        router.ready()
        self.gateway = Child(
            [
                "-m",
                "gateway",
                "--control-port",
                str(self.sim_ports[0]),
                "--log-port",
                str(self.sim_ports[1]),
                *zenoh_connect_args(self.zport),
                *gateway_args,
            ]
        )
        children.append(self.gateway)
        self.gateway.ready()
        self.sim = self.start_sim()

    def start_sim(self) -> SimProcess:
        sim = SimProcess("--control-port", str(self.sim_ports[0]), "--log-port", str(self.sim_ports[1]), *zenoh_connect_args(self.zport))
        self.children.append(sim)
        return sim


def latest(session: zenoh.Session, key: str) -> bytes | None:
    for reply in session.get(key, timeout=5):
        if reply.ok is not None:
            return reply.ok.payload.to_bytes()
    return None


def truth(session: zenoh.Session) -> Pose:
    payload = latest(session, "robot/sim/truth")
    assert payload is not None
    return decode(Pose, payload)


def health(session: zenoh.Session) -> GatewayHealth | None:
    payload = latest(session, "robot/gateway/health")
    return None if payload is None else decode(GatewayHealth, payload)


def test_drive_through_zenoh_and_watch_the_state(children: list[Child]) -> None:
    rig = Rig(children, "--cmd-timeout", "0")
    with zenoh.open(client_config(rig.zport)) as session:
        wait_for(lambda: (h := health(session)) is not None and h.control.state == "connected", what="a connected gateway")
        alive = list(session.liveliness().get("robot/alive/*", timeout=5))
        assert any(str(r.ok.key_expr) == "robot/alive/gateway" for r in alive if r.ok is not None)
        impulses: list[WheelImpulses] = []
        statuses: list[bytes] = []
        session.declare_subscriber("robot/wheels/impulses", lambda s: impulses.append(decode(WheelImpulses, s.payload.to_bytes())))
        session.declare_subscriber("robot/status", lambda s: statuses.append(s.payload.to_bytes()))
        # no encoding header, trailing newline: what `zenoh put` sends
        session.put("robot/cmd_vel", b'{"linear":{"x":0.2},"angular":{"z":0.5}}\n')
        wait_for(lambda: truth(session).yaw > 0.2, what="a left turn in the true pose")
        pose = truth(session)
        assert pose.y > 0 and pose.x > 0
        # with a JSON encoding header and without a newline
        session.put("robot/cmd_vel", json.dumps({"linear": {"x": 0.0}}), encoding=zenoh.Encoding.APPLICATION_JSON)
        wait_for(lambda: abs(truth(session).v) < 1e-9, what="a stop")
        # the newest impulse sample may still be one polled before the stop, on a loaded machine: wait for rest
        wait_for(
            lambda: len(impulses) > 20 and impulses[-1].left == 0 and impulses[-1].right == 0 and statuses,
            what="impulses at rest and a status",
        )
        assert json.loads(statuses[-1])["state_name"] == "READY"
    assert rig.gateway.stop(signal.SIGINT) == 0


def test_restarting_the_robot_reconnects_within_three_seconds(children: list[Child]) -> None:
    rig = Rig(children, "--cmd-timeout", "0")
    with zenoh.open(client_config(rig.zport)) as session:
        impulses: list[WheelImpulses] = []
        session.declare_subscriber("robot/wheels/impulses", lambda s: impulses.append(decode(WheelImpulses, s.payload.to_bytes())))
        wait_for(lambda: len(impulses) > 10, what="impulses")
        rig.sim.stop(signal.SIGKILL)
        time.sleep(0.5)
        down = health(session)
        assert down is not None and down.control.state != "connected"
        session.put("robot/cmd_vel", b'{"linear":{"x":0.3}}')  # refused while down, never replayed later
        count = len(impulses)
        restarted = time.monotonic()
        # the truth publisher of the new sim needs the same Zenoh port: the old one is dead, so it is free
        rig.sim = rig.start_sim()
        wait_for(lambda: (h := health(session)) is not None and h.control.state == "connected", what="a reconnect")
        wait_for(lambda: len(impulses) > count + 5, what="impulses to resume")
        assert time.monotonic() - restarted < 3.0 + 5.0  # 3 s from the robot being back; slack for process start
        time.sleep(0.5)
        assert truth(session).x == pytest.approx(0.0, abs=1e-9)  # nothing was replayed from before the outage
        h = health(session)
        assert h is not None and h.control.reconnects >= 1


def test_hostile_zenoh_payloads_leave_the_gateway_serving(children: list[Child]) -> None:
    rig = Rig(children, "--cmd-timeout", "0")
    with zenoh.open(client_config(rig.zport)) as session:
        errors: list[bytes] = []
        session.declare_subscriber("robot/errors", lambda s: errors.append(s.payload.to_bytes()))
        wait_for(lambda: (h := health(session)) is not None and h.control.state == "connected", what="a connected gateway")
        session.put("robot/cmd_vel", b'{"linear":{"x":0.1}}')
        wait_for(lambda: truth(session).v == pytest.approx(0.1), what="motion")
        hostile = [
            b"\x00\x01\x02",
            b'{"linear":{"x":NaN}}',
            b'{"linear":{"x":Infinity}}',
            b'{"linear":{"x":1e308},"angular":{"z":-1e308}}',
            b'{"linear":{"x":"fast"}}',
            b"A" * (1024 * 1024),
            b'{"linear":{"x":0.1}' + b" " * (1024 * 1024) + b"}",
        ]
        block = zenoh.CongestionControl.BLOCK  # every hostile payload must arrive, none dropped on the way
        rejected = 0
        for payload in hostile * 2:
            # one at a time: each input keeps only its newest sample, so a burst would be superseded (and counted so)
            for key in ("robot/cmd_vel", "robot/estop"):
                session.put(key, payload, congestion_control=block)
                rejected += 1
                wait_for(
                    lambda at_least=rejected: (h := health(session)) is not None and h.rejected_inputs >= at_least,
                    what=f"the hostile payload {payload[:20]!r} on {key} to be rejected",
                )
        # the robot's links report on errors too (source "robot": the gateway may start before the simulator listens)
        inputs = lambda: [r for r in map(json.loads, errors) if r["source"] != "robot"]  # noqa: E731
        wait_for(lambda: len(inputs()) >= 5, what="error reports")
        reports = inputs()
        assert all(r["reason"] and r["key"] in ("robot/cmd_vel", "robot/estop") for r in reports), reports
        assert any("larger than" in r["reason"] for r in reports)
        # a hostile payload on estop fails safe: the stop is engaged, and only a valid release lifts it
        wait_for(lambda: truth(session).v == 0.0, what="the robot stopped by the engaged e-stop")
        assert health(session).estop  # type: ignore[union-attr]
        session.put("robot/estop/release", b'{"engaged": false}')
        wait_for(lambda: (h := health(session)) is not None and not h.estop, what="the release")
        session.put("robot/cmd_vel", b'{"linear":{"x":0.05}}')
        wait_for(lambda: truth(session).v == pytest.approx(0.05), what="the gateway still serving")
    assert rig.gateway.proc.poll() is None


def test_sigterm_stops_the_robot_and_exits_within_two_seconds(children: list[Child]) -> None:
    rig = Rig(children, "--cmd-timeout", "0")
    with zenoh.open(client_config(rig.zport)) as session:
        wait_for(lambda: (h := health(session)) is not None and h.control.state == "connected", what="a connected gateway")
        session.put("robot/cmd_vel", b'{"linear":{"x":0.2}}')
        wait_for(lambda: truth(session).v == pytest.approx(0.2), what="motion")
        start = time.monotonic()
        assert rig.gateway.stop(signal.SIGTERM) == 0
        assert time.monotonic() - start < 2.0
        wait_for(lambda: truth(session).v == 0.0, what="the robot to be stopped by the gateway's exit")
        alive = [r for r in session.liveliness().get("robot/alive/gateway", timeout=2) if r.ok is not None]
        assert alive == []


def test_bad_settings_exit_with_a_clear_message(children: list[Child]) -> None:
    proc = Child(["-m", "blackmetal.gateway", "--poll-hz", "0"])
    children.append(proc)
    assert proc.proc.wait(20) == 2
    proc.stop()
    assert "poll_hz must be positive" in proc.output() and "Traceback" not in proc.output()
