"""One robot per prefix and per Zenoh network: blackmetal processes meet only what they are told to reach."""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Iterator

import pytest
import zenoh
from helpers import Child, client_config, free_port, wait_for

from blackmetal.schemas import Keys, Pose, decode

pytestmark = pytest.mark.integration

KEYS = Keys()


def _truth(session: zenoh.Session) -> Pose:
    def ask() -> Pose | None:
        for reply in session.get(KEYS.sim_truth, timeout=2):
            if reply.ok is not None:
                return decode(Pose, reply.ok.payload.to_bytes())
        return None

    pose: Pose = wait_for(ask, what="the simulator's truth")
    return pose


def drive_one_not_the_other(mover: zenoh.Session, other: zenoh.Session) -> None:
    """cmd_vel through ``mover`` moves its simulator; the other demo's truth does not change."""
    start = _truth(other)
    for _ in range(15):
        mover.put(KEYS.cmd_vel, b'{"linear":{"x":0.3}}')
        time.sleep(0.1)
    wait_for(lambda: _truth(mover).x > 0.2, what="the driven demo to move")
    end = _truth(other)
    assert (end.x, end.y) == (start.x, start.y)  # the other demo never moved


@contextlib.contextmanager
def two_demos() -> Iterator[tuple[int, int]]:
    """Two `blackmetal up` on one host with default flags; their Zenoh ports."""
    ports = (free_port(), free_port())
    ups = [Child(["-m", "blackmetal", "up", "-l", f"tcp/127.0.0.1:{port}"]) for port in ports]
    try:
        for up in ups:
            up.ready(timeout=60)
        yield ports
    finally:
        for up in ups:
            up.stop()


def test_two_demos_on_one_host_are_independent() -> None:
    """Default flags only (no --no-multicast-scouting anywhere): a command to one demo never moves the other."""
    with two_demos() as ports, zenoh.open(client_config(ports[0])) as a, zenoh.open(client_config(ports[1])) as b:
        poses_a: list[bytes] = []
        a.declare_subscriber(KEYS.pose, lambda s: poses_a.append(s.payload.to_bytes()))
        drive_one_not_the_other(a, b)
        alive = [str(r.ok.key_expr) for r in a.liveliness().get("**/alive/**", timeout=2) if r.ok is not None]
        assert sorted(alive) == sorted({KEYS.alive_gateway, KEYS.alive_odometry, KEYS.alive_sim, KEYS.alive_nav})  # each once: A's only
        time.sleep(1.0)
        rates = [json.loads(p)["stamp"] for p in poses_a[-60:]]
        assert len(rates) >= 2 and (len(rates) - 1) / (rates[-1] - rates[0]) < 60  # 50 poses/s, not 100


@pytest.mark.parametrize("service", ["gateway", "odometry", "sim", "nav"])
def test_a_port_in_use_is_one_sentence_and_a_router_down_is_waited_for(service: str) -> None:
    import re
    import signal
    import socket
    import subprocess
    import sys

    extra = ["--control-port", "0", "--log-port", "0"] if service == "sim" else []
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        in_use = subprocess.run(
            [sys.executable, "-m", "blackmetal", service, *extra, "-l", f"tcp/127.0.0.1:{port}"],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
    assert in_use.returncode == 1, in_use.stderr
    errors = [line for line in in_use.stderr.splitlines() if "blackmetal" in line and "INFO" not in line]
    assert errors == [f"blackmetal {service}: cannot listen on tcp/127.0.0.1:{port}: the port is in use by another process "
                      "(another `blackmetal up`, a router or a service?); stop it, or choose another port with -l tcp/127.0.0.1:PORT"]  # fmt: skip
    assert "ready" not in in_use.stdout and "Traceback" not in in_use.stderr
    # a router that is not up yet is waited for (systemd and compose start units in parallel): tests/integration/test_start_order.py
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    down = Child(["-m", "blackmetal", service, *extra, "-m", "client", "-e", endpoint])
    try:
        down.wait_line(rf"waiting for {re.escape(endpoint)} \(router or hub\)")
        assert down.poll() is None
    finally:
        assert down.stop(signal.SIGINT) == 0
    assert "Traceback" not in down.output() and " ready" not in down.output()


def test_a_second_gateway_odometry_or_nav_on_a_prefix_refuses_to_start() -> None:
    import subprocess
    import sys

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = Child(["-m", "blackmetal", "router", "-l", endpoint])
    hub.ready()
    first = []
    try:
        for service in ("gateway", "odometry", "nav"):
            first.append(Child(["-m", "blackmetal", service, "-e", endpoint]))
            first[-1].ready()
        for service, role in (("gateway", "gateway"), ("odometry", "odometry service"), ("nav", "navigation service")):
            second = subprocess.run(
                [sys.executable, "-m", "blackmetal", service, "-e", endpoint], capture_output=True, text=True, timeout=60
            )
            assert second.returncode == 2 and "Traceback" not in second.stderr
            assert f"another {role} is already alive on prefix 'robot'" in second.stderr and "--prefix" in second.stderr
        other = Child(["-m", "blackmetal", "odometry", "-e", endpoint, "--prefix", "fleet/b"])  # another prefix is fine
        first.append(other)
        other.ready()
    finally:
        for child in [*first, hub]:
            child.stop()


def test_a_peer_that_met_two_demos_does_not_link_them() -> None:
    """A plain Zenoh peer (its default config: gossip on) connects to both demos for 2 s and leaves; B's cmd_vel never drives A."""
    with two_demos() as ports:
        conf = zenoh.Config()
        conf.insert_json5("scouting/multicast/enabled", "false")  # gossip stays at Zenoh's default
        conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}" for port in ports]))
        with zenoh.open(conf):
            time.sleep(2.0)
        time.sleep(1.0)
        with zenoh.open(client_config(ports[0])) as a, zenoh.open(client_config(ports[1])) as b:
            drive_one_not_the_other(b, a)


def test_one_default_endpoint_for_services_and_tools() -> None:
    """No Zenoh flags: every process is a client of tcp/127.0.0.1:7447 (where up and router listen); -l makes a hub of it."""
    from blackmetal.cli import build_parser
    from blackmetal.gateway.settings import GatewaySettings
    from blackmetal.odometry_service.settings import OdometrySettings
    from blackmetal.ros2.settings import Ros2Settings
    from blackmetal.runtime.settings import load_settings
    from blackmetal.runtime.zenoh_setup import DEFAULT_ENDPOINT, zenoh_settings
    from blackmetal.sim.settings import SimSettings

    assert DEFAULT_ENDPOINT == "tcp/127.0.0.1:7447"
    parser = build_parser()
    for command, cls in (("gateway", GatewaySettings), ("odometry", OdometrySettings), ("ros2", Ros2Settings), ("sim", SimSettings)):
        plain = load_settings(cls, parser.parse_args([command, *(["--zenoh"] if command == "sim" else [])]), environ={})
        assert plain.zenoh.endpoints == [DEFAULT_ENDPOINT] and json.loads(plain.zenoh.to_config().get_json("mode")) == "client"
        hub = load_settings(cls, parser.parse_args([command, "-l", "tcp/127.0.0.1:7500"]), environ={})
        assert hub.zenoh.endpoints == [] and hub.zenoh.is_hub
        given = load_settings(cls, parser.parse_args([command, "-e", "tcp/127.0.0.1:7501"]), environ={})
        conf = given.zenoh.to_config(wait=True)
        assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7501"]
        assert json.loads(conf.get_json("mode")) == "client" and json.loads(conf.get_json("connect/timeout_ms")) == -1
    for tool in (["watch"], ["teleop"], ["robots"], ["estop", "on"], ["record"], ["square"]):
        settings = zenoh_settings(parser.parse_args(tool))
        assert settings.endpoints == [DEFAULT_ENDPOINT]
        assert json.loads(settings.to_config().get_json("connect/timeout_ms")) != -1  # the tools fail at once
