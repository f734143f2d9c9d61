"""Test helpers: free ports, loopback Zenoh configs, child processes, condition waits."""

from __future__ import annotations

import json
import os
import random
import re
import socket
import time
from collections.abc import Callable
from typing import Any

import zenoh

from blackmetal.runtime.harness import ChildFailed, ServiceProcess

#: Payloads on estop whose meaning is plainly "true", in the shapes clients send: each must engage the stop.
TRUE_ESTOPS = [
    b'{"engaged": true, "reason": "operator"}',
    b'{"engaged": 1}',
    b'{"engaged": "true"}',
    b"true",
    b'{"data": true}',  # a ROS bridge's std_msgs/Bool
    b'{"Engaged": true}',
    b'{"engaged": true}\x00',  # a C client's terminator
]

#: Generous: these tests must hold on a loaded 2-core machine.
TIMEOUT = 20.0


def _ephemeral_low() -> int:
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as ranges:
            return int(ranges.read().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768  # Linux's default; macOS starts at 49152


def _port_slice() -> range:
    """This worker's own ports: below the kernel's ephemeral range, one slice per xdist worker."""
    low, high = 10000, max(_ephemeral_low(), 12000)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw")
    index = int(worker) % 8 if worker.isdigit() else 0
    size = (high - low) // 8
    return range(low + index * size, low + (index + 1) * size)


_PORTS = _port_slice()
_next_port = _PORTS.start + random.randrange(len(_PORTS))  # another run on this machine starts elsewhere


def free_port() -> int:
    """A port nothing listens on, and that no outgoing connection can take before the test binds it.

    Asking the kernel for port 0 returns a port from its ephemeral range, which the
    next connect() of any process may take as its local port in the moment before
    the child binds it (CI saw "port in use" this way). Ports below that range are
    never handed out by the kernel, and each xdist worker walks its own slice.
    """
    global _next_port
    for _ in range(len(_PORTS)):
        port = _next_port
        _next_port = _PORTS.start + (port + 1 - _PORTS.start) % len(_PORTS)
        if _bindable(port):
            return port
    raise AssertionError(f"no free port in {_PORTS.start}-{_PORTS.stop - 1}")


def free_ports(count: int) -> int:
    """A base port B with B ... B + count - 1 all free (recipes number their robots' ports from a base)."""
    global _next_port
    for _ in range(len(_PORTS)):
        base = free_port()
        if base + count > _PORTS.stop:
            continue
        if all(_bindable(port) for port in range(base + 1, base + count)):
            _next_port = _PORTS.start + (base + count - _PORTS.start) % len(_PORTS)  # the next caller starts after the block
            return base
    raise AssertionError(f"no {count} consecutive free ports in {_PORTS.start}-{_PORTS.stop - 1}")


def _bindable(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        try:
            sock.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def wait_for(condition: Callable[[], Any], timeout: float = TIMEOUT, interval: float = 0.02, what: str = "condition") -> Any:
    """Poll ``condition`` until it returns something truthy; fail after ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(interval)


def zenoh_listen_args(port: int) -> list[str]:
    return ["--no-multicast-scouting", "-l", f"tcp/127.0.0.1:{port}"]


def zenoh_connect_args(port: int) -> list[str]:
    return ["--no-multicast-scouting", "-e", f"tcp/127.0.0.1:{port}"]


def client_config(port: int) -> zenoh.Config:
    """A client of the process listening on ``port`` (no discovery: only that endpoint)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    return conf


class Child(ServiceProcess):
    """A child process through the project's one harness; ``wait_line`` checks what a person would read."""

    def __init__(self, args: list[str], env: dict[str, str] | None = None, launcher: list[str] | None = None) -> None:
        name = args[2] if args[:2] == ["-m", "blackmetal"] and len(args) > 2 else " ".join(args[:2])
        super().__init__(name, args, env=env, launcher=launcher)

    def wait_line(self, pattern: str, timeout: float = TIMEOUT) -> re.Match[str]:
        """The first line of output matching ``pattern`` (for assertions on human output, not readiness)."""
        regex = re.compile(pattern)

        def found() -> re.Match[str] | None:
            for line in list(self.lines):
                match = regex.search(line)
                if match:
                    return match
            if self.proc.poll() is not None:
                raise AssertionError(f"{self.args} exited with {self.proc.returncode}:\n{self.output()}")
            return None

        try:
            return wait_for(found, timeout, what=f"a line matching {pattern!r}")
        except AssertionError as exc:
            raise AssertionError(f"{exc}\noutput so far:\n{self.output()}") from None

    def ready(self, timeout: float = TIMEOUT) -> dict[str, Any]:
        """Wait for the child's ready announcement; fail the test with its output if it never comes."""
        try:
            return self.wait_ready(timeout)
        except ChildFailed as exc:
            raise AssertionError(str(exc) + "\n" + self.output()) from None


class SimProcess(Child):
    """``blackmetal sim`` on free ports; ``control_port``/``log_port`` once ready."""

    def __init__(self, *extra: str, launcher: list[str] | None = None) -> None:
        super().__init__(["-m", "blackmetal", "sim", "--control-port", "0", "--log-port", "0", *extra], launcher=launcher)
        info = self.ready()
        self.host = info["host"]
        self.control_port = int(info["control_port"])
        self.log_port = int(info["log_port"])


def start_robot(
    children: list[Child],
    zport: int,
    sim_args: tuple[str, ...] = (),
    gateway_args: tuple[str, ...] = (),
    odometry_args: tuple[str, ...] = (),
) -> tuple[SimProcess, Child, Child]:
    """The simulator listening on ``zport`` (the hub), a gateway and an odometry as its clients; all ready, all in ``children``."""
    sim = SimProcess(*sim_args, *zenoh_listen_args(zport))
    children.append(sim)
    gateway = Child(
        [
            "-m",
            "gateway",
            "--control-port",
            str(sim.control_port),
            "--log-port",
            str(sim.log_port),
            *gateway_args,
            *zenoh_connect_args(zport),
        ]
    )
    odometry = Child(["-m", "odometry_service", *odometry_args, *zenoh_connect_args(zport)])
    children.extend([gateway, odometry])
    gateway.ready()
    odometry.ready()
    return sim, gateway, odometry


#: A process that puts cmd_vel on ``argv[2]`` at full speed for ``argv[3]`` s through the Zenoh endpoint on port ``argv[1]``
#: (``argv[4]``: where its speeds start, so two flooders differ).
FLOODER = """
import sys, time, zenoh
conf = zenoh.Config()
conf.insert_json5("connect/endpoints", '["tcp/127.0.0.1:%s"]' % sys.argv[1])
conf.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(conf) as session:
    publisher = session.declare_publisher(sys.argv[2])
    end, i = time.monotonic() + float(sys.argv[3]), int(sys.argv[4])
    while time.monotonic() < end:
        publisher.put(b'{"linear":{"x":%.4f}}' % (0.1 + 0.0001 * (i % 500)))
        i += 1
"""
