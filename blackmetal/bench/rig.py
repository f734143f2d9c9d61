"""The processes a figure stands up and what it reads of them.

Each goes on the figure's ExitStack from the moment it exists, so it stops however the figure ends.
"""

from __future__ import annotations

import os
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING

from blackmetal.runtime.harness import ServiceProcess
from blackmetal.schemas import Keys

from .children import spawn
from .peers import RobotProcess, _zenoh_conf, free_port

if TYPE_CHECKING:
    import zenoh

KEYS = Keys()

CLK_TCK = os.sysconf("SC_CLK_TCK")


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # utime + stime


def cpu_window(pids: dict[str, int], seconds: float) -> dict[str, float]:
    """Each process's CPU share (cores) over the next ``seconds``."""
    cpu0, t0 = {name: cpu_seconds(pid) for name, pid in pids.items()}, time.monotonic()
    time.sleep(seconds)
    cpu1, t1 = {name: cpu_seconds(pid) for name, pid in pids.items()}, time.monotonic()
    return {name: (cpu1[name] - cpu0[name]) / (t1 - t0) for name in pids}


def service(stack: ExitStack, name: str, command: list[str], module: str = "blackmetal", timeout: float = 10.0) -> ServiceProcess:
    """``python -m MODULE COMMAND...`` as a child, stopped when ``stack`` closes; returns once it says it is ready."""
    child = spawn(name, ["-m", module, *command])
    stack.callback(child.stop, timeout=timeout)
    child.wait_ready()
    return child


def peer(stack: ExitStack, name: str, args: list[str]) -> ServiceProcess:
    """One of the bench's own peer processes (``python -m blackmetal.bench NAME ARGS``)."""
    return service(stack, name, [name, *args], "blackmetal.bench", timeout=3)


def latch_args(stack: ExitStack) -> list[str]:
    """A bench's gateway keeps its e-stop latch in a folder of its own, released at first: its robots are the bench's own."""
    folder = stack.enter_context(tempfile.TemporaryDirectory(prefix="blackmetal-bench-state-"))
    return ["--state-dir", folder, "--unsafe-start-released"]


def client_service(stack: ExitStack, command: str, zport: int, listen: int | None = None) -> ServiceProcess:
    """``blackmetal odometry`` or ``ros2``, a client of the gateway's endpoint; with ``listen``, a peer others reach directly."""
    listening = ["-l", f"tcp/127.0.0.1:{listen}"] if listen else []
    return service(stack, command, [command, "-e", f"tcp/127.0.0.1:{zport}", *listening])


def session(stack: ExitStack, zport: int) -> "zenoh.Session":
    """The bench's own Zenoh session, a client of the process listening on ``zport``."""
    import zenoh

    return stack.enter_context(zenoh.open(_zenoh_conf(connect=zport)))


def robot_and_gateway(stack: ExitStack, poll_hz: float = 50.0) -> tuple[RobotProcess, int, ServiceProcess]:
    """A mini robot and its gateway listening on a free Zenoh port, polling at ``poll_hz``, without a command timeout:
    most figures start there."""
    robot = RobotProcess(stack)
    zport = free_port()
    gateway = service(
        stack,
        "gateway",
        ["gateway", "--control-port", str(robot.control_port), "--log-port", str(robot.log_port),
         "--poll-hz", str(poll_hz), "--cmd-timeout", "0", *latch_args(stack), "--no-multicast-scouting", "-l", f"tcp/127.0.0.1:{zport}"],
    )  # fmt: skip
    return robot, zport, gateway


def wait_polls(robot: RobotProcess) -> None:
    deadline = time.monotonic() + 20.0
    while not robot.dump()["polls"]:
        if time.monotonic() > deadline:
            raise TimeoutError("the gateway did not poll the robot within 20 s")
        time.sleep(0.1)
