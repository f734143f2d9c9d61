"""A newcomer's mistakes end in one sentence that names what to check: a busy port for the simulator and the router."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers import Child, free_port

pytestmark = pytest.mark.integration


def blackmetal(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "blackmetal", *args], capture_output=True, text=True, timeout=60)


@pytest.fixture
def busy_port() -> Iterator[int]:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", free_port()))
        sock.listen()
        yield sock.getsockname()[1]


@pytest.mark.parametrize("which", ["control", "log"])
def test_the_simulator_on_a_busy_port_says_which_and_what_to_do(busy_port: int, which: str) -> None:
    other = "log" if which == "control" else "control"
    done = blackmetal("sim", f"--{which}-port", str(busy_port), f"--{other}-port", "0")
    assert done.returncode == 1 and done.stderr.count("\n") == 1 and "Errno" not in done.stderr, done.stderr
    assert f"cannot listen on 127.0.0.1:{busy_port} (the {which} port): the port is in use" in done.stderr
    assert f"--{which}-port PORT" in done.stderr


def test_a_second_router_names_the_port_it_could_not_take_from_a_config_file(tmp_path: Path) -> None:
    port = free_port()
    config = tmp_path / "router.json5"
    config.write_text(
        f'{{ mode: "router", listen: {{ endpoints: ["tcp/127.0.0.1:{port}"] }}, scouting: {{ multicast: {{ enabled: false }} }} }}\n'
    )
    first = Child(["-m", "blackmetal", "router", "-c", str(config)])
    try:
        first.ready()
        first.wait_line(rf"blackmetal router ready: \w+ listening on tcp/127\.0\.0\.1:{port}$")  # the endpoints, not JSON
        second = blackmetal("router", "-c", str(config))
        assert second.returncode == 1 and second.stderr.count("\n") == 1, second.stderr
        assert f"cannot listen on tcp/127.0.0.1:{port}: the port is in use" in second.stderr
    finally:
        first.stop()


def test_an_invalid_port_is_said_as_such() -> None:
    done = blackmetal("watch", "-e", "tcp/127.0.0.1:99999", "--wait", "1")
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "has an invalid port '99999': a port is a number from 1 to 65535" in done.stderr


def test_a_service_waiting_for_a_name_that_does_not_resolve_says_so() -> None:
    gateway = Child(["-m", "blackmetal", "gateway", "-e", "tcp/nonexistent.invalid:7447", "--no-multicast-scouting"])
    try:
        gateway.wait_line("waiting for tcp/nonexistent.invalid:7447")
        gateway.wait_line("the host name 'nonexistent.invalid' does not resolve: check the name in -e")
    finally:
        gateway.stop()


def test_estop_with_no_gateway_answers_within_its_timeout_not_its_wait() -> None:
    port = free_port()
    router = Child(["-m", "blackmetal", "router", "-l", f"tcp/127.0.0.1:{port}", "--no-multicast-scouting"])
    try:
        router.ready()
        start = time.monotonic()
        done = blackmetal("estop", "on", "-e", f"tcp/127.0.0.1:{port}", "--wait", "30", "--timeout", "2")
        took = time.monotonic() - start
        assert done.returncode == 1 and done.stderr.count("\n") == 1, done.stderr
        assert "no gateway answered on robot/gateway/health within 2 s" in done.stderr
        assert took < 15, f"{took:.1f} s: it waited for --wait 30, not its --timeout 2"
    finally:
        router.stop()


def test_watch_with_a_duration_and_no_gateway_gives_up_within_that_duration() -> None:
    port = free_port()
    router = Child(["-m", "blackmetal", "router", "-l", f"tcp/127.0.0.1:{port}", "--no-multicast-scouting"])
    try:
        router.ready()
        start = time.monotonic()
        done = blackmetal("watch", "-e", f"tcp/127.0.0.1:{port}", "--wait", "30", "--duration", "2")
        took = time.monotonic() - start
        assert done.returncode == 1 and "no gateway answered on robot/gateway/health within 2 s" in done.stderr, done.stderr
        assert took < 15, f"{took:.1f} s: it waited for --wait 30, not its --duration 2"
    finally:
        router.stop()
