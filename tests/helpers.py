"""Test helpers: free ports, loopback Zenoh configs, child processes, condition waits."""

from __future__ import annotations

import json
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import zenoh

from blackmetal import robot_model as model
from blackmetal.bench.synth import Leg
from blackmetal.gateway.host import Message
from blackmetal.gateway.latch import AT_START, Latch, Untrusted
from blackmetal.robot_model import arc_step
from blackmetal.runtime import ports
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


def free_port() -> int:
    """A free loopback port below the kernel's ephemeral range, in this xdist worker's own slice."""
    return ports.free_port()


def free_ports(count: int) -> int:
    """A base port B with B ... B + count - 1 all free (recipes number their robots' ports from a base)."""
    return ports.free_port(count)


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
    odometry = Child(["-m", "blackmetal.odometry_service", *odometry_args, *zenoh_connect_args(zport)])
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


def exact_pose(legs: list[Leg], separation: float = model.WHEEL_SEPARATION) -> tuple[float, float, float]:
    """Where ``legs`` end, integrated in closed form: the answer synthetic logs are checked against."""
    x = y = yaw = 0.0
    for leg in legs:
        x, y, yaw = arc_step(x, y, yaw, leg.left * leg.duration, leg.right * leg.duration, separation)
    return x, y, yaw


@dataclass
class MemoryLatchStore:
    """A latch kept in memory, for tests: ``latch`` as saved; ``failing``: why saving fails (None: it works)."""

    latch: Latch | Untrusted = field(default_factory=lambda: Latch(False, 0.0, AT_START))
    failing: str | None = None
    saves: list[Latch] = field(default_factory=list)
    where: str = "memory"

    def load(self) -> Latch | Untrusted:
        return self.latch

    def save(self, latch: Latch) -> str | None:
        if self.failing is not None:
            return self.failing
        self.latch = latch
        self.saves.append(latch)
        return None


M = TypeVar("M", bound=Message)


@dataclass
class RecordingOutput:
    """Where a test's gateway publishes: every message kept, by type (each type has its key: :meth:`Keys.message_for`)."""

    messages: dict[type, list[Any]] = field(default_factory=dict)

    def __call__(self, message: Message) -> None:
        self.messages.setdefault(type(message), []).append(message)

    def of(self, kind: type[M]) -> list[M]:
        """The messages of one type so far, in order (the list grows as more come)."""
        return self.messages.setdefault(kind, [])
