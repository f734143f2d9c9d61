"""``blackmetal up``: the simulated robot, the gateway and the odometry service in one command.

Each runs as its own process; this one holds the Zenoh endpoint that clients
connect to (``tcp/127.0.0.1:7447`` unless ``-l`` says otherwise), prints how
to drive the robot, then a live one-line status. Ctrl-C stops everything
within 3 s; a child that dies is reported with its last lines.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import zenoh

from schemas import ErrorReport, GatewayHealth, Pose
from schemas import robot as facts

from .client import Latest
from .errors import ConfigError
from .signals import stop_on_signals
from .zenoh_config import add_zenoh_arguments, validate_prefix, zenoh_settings

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
STOP_BUDGET_S = 3.0


@dataclass
class ChildProcess:
    """A service process whose output is kept (last lines) by a reader thread."""

    name: str
    args: list[str]
    verbose: bool = False
    lines: deque[str] = field(default_factory=lambda: deque(maxlen=40))

    def start(self) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, *self.args],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
            start_new_session=True,  # Ctrl-C reaches us only; we stop the children in order
        )
        self._ready = threading.Event()
        self._reader = threading.Thread(target=self._read, name=f"{self.name}-output", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            line = line.rstrip("\n")
            self.lines.append(line)
            if self.verbose:
                print(f"[{self.name}] {line}", flush=True)

    def wait_line(self, pattern: str, timeout: float) -> re.Match[str]:
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in list(self.lines):
                match = regex.search(line)
                if match:
                    return match
            if self.proc.poll() is not None:
                break
            time.sleep(0.02)
        raise ChildFailed(self, "did not start" if self.proc.poll() is None else f"exited with code {self.proc.returncode}")

    def tail(self, count: int = 15) -> str:
        return "\n".join(f"    {line}" for line in list(self.lines)[-count:]) or "    (no output)"

    def signal(self, sig: int) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.send_signal(sig)
            except ProcessLookupError:
                pass


class ChildFailed(Exception):
    def __init__(self, child: ChildProcess, what: str) -> None:
        self.child = child
        super().__init__(f"{child.name} {what}; its last lines:\n{child.tail()}")


def _child_zenoh_args(args: argparse.Namespace, hub: str) -> list[str]:
    """Children join as loopback-only peers of our session (plus any routers given with -e)."""
    out = ["--no-multicast-scouting", "-e", hub, "-l", "tcp/127.0.0.1:0"]
    for endpoint in args.connect or []:
        out += ["-e", endpoint]
    if args.config:
        out += ["-c", args.config]
    return out


def _hub_endpoint(listen: str) -> str:
    """Where a local child connects to reach a listener (0.0.0.0 / [::] become loopback)."""
    proto, _, address = listen.partition("/")
    host, _, port = address.rpartition(":")
    if host in ("0.0.0.0", "[::]", ""):
        host = "127.0.0.1"
    return f"{proto}/{host}:{port}"


def python_snippet(prefix: str, endpoint: str) -> str:
    """A shell command that drives the robot for 3 s from plain Python (no single quotes inside)."""
    code = (
        "import zenoh, time; c = zenoh.Config(); "
        f'c.insert_json5("connect/endpoints", "[\\"{endpoint}\\"]"); s = zenoh.open(c); '
        f'[(s.put("{prefix}/cmd_vel", "{{\\"linear\\":{{\\"x\\":0.2}},\\"angular\\":{{\\"z\\":0.5}}}}"), time.sleep(0.1)) '
        "for _ in range(30)]; s.close()"
    )
    return f"python3 -c '{code}'"


def _drive_help(prefix: str, endpoint: str) -> str:
    return "\n".join(
        [
            "Drive it from any Zenoh client (commands time out after 0.5 s: publish at 5 Hz or more):",
            f"  blackmetal teleop -e {endpoint}",
            f"  {python_snippet(prefix, endpoint)}",
            f"  z_put -e {endpoint} -k {prefix}/cmd_vel -p '{{\"linear\":{{\"x\":0.2}}}}'   # zenoh's own CLI, if installed",
            f"Watch it:  blackmetal watch -e {endpoint}    Pose:  z_get -e {endpoint} -s {prefix}/pose",
            "Ctrl-C stops everything.",
        ]
    )


class StatusLine:
    """Subscriptions for the live one-line status."""

    def __init__(self, session: zenoh.Session, prefix: str, with_truth: bool) -> None:
        self.health = Latest(session, f"{prefix}/gateway/health", GatewayHealth)
        self.pose = Latest(session, f"{prefix}/pose", Pose)
        self.truth = Latest(session, f"{prefix}/sim/truth", Pose) if with_truth else None
        self.errors = Latest(session, f"{prefix}/errors", ErrorReport)
        self._last_count = 0
        self._last_time = time.monotonic()

    def render(self) -> str:
        now = time.monotonic()
        rate = (self.pose.count - self._last_count) / max(now - self._last_time, 1e-6)
        self._last_count, self._last_time = self.pose.count, now
        h: GatewayHealth | None = self.health.value
        parts = []
        if h is None:
            parts.append("gateway: waiting")
        else:
            parts.append(f"link {h.control.state}/{h.log.state}")
            parts.append(f"poll {h.poll_hz:.0f} Hz")
            if h.estop:
                parts.append("E-STOP")
            if h.cmd_timeout_active:
                parts.append("idle")
        p: Pose | None = self.pose.value
        if p is None:
            parts.append("pose: waiting")
        else:
            parts.append(f"pose x={p.x:+.3f} y={p.y:+.3f} yaw={math.degrees(p.yaw):+6.1f}° v={p.v:+.2f} w={p.w:+.2f}")
            parts.append(f"{rate:.0f} poses/s")
        if self.truth is not None and self.truth.value is not None:
            t: Pose = self.truth.value
            parts.append(f"truth x={t.x:+.3f} y={t.y:+.3f}")
        if self.errors.count:
            parts.append(f"errors {self.errors.count}")
        return " | ".join(parts)


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="blackmetal up", description=__doc__)
    parser.add_argument("--robot", metavar="HOST", help="drive a real robot at HOST instead of the simulator")
    parser.add_argument("--control-port", type=int, default=facts.CONTROL_PORT, help="robot control port with --robot (default 665)")
    parser.add_argument("--log-port", type=int, default=facts.LOG_PORT, help="robot log port with --robot (default 664)")
    parser.add_argument("--prefix", default=facts.DEFAULT_PREFIX, help="key-expression prefix (default robot)")
    parser.add_argument("--poll-hz", type=float, default=50.0, help="wheel polls per second (default 50)")
    parser.add_argument("--seed", type=int, help="simulator fault seed")
    parser.add_argument("--status-interval", type=float, default=0.5, help="seconds between status updates")
    parser.add_argument("-v", "--verbose", action="store_true", help="show the services' own log lines")
    add_zenoh_arguments(parser)
    return parser


def run(args: argparse.Namespace) -> int:
    try:
        validate_prefix(args.prefix)
        settings = zenoh_settings(args)
        if not settings.listen:
            settings.listen = [DEFAULT_LISTEN]
        conf = settings.to_config()
    except ConfigError as exc:
        print(f"blackmetal up: {exc}", file=sys.stderr)
        return 2
    hub = _hub_endpoint(settings.listen[0])
    try:
        session = zenoh.open(conf)
    except Exception as exc:  # zenoh raises ZError with the OS reason
        print(
            f"blackmetal up: cannot open Zenoh listening on {', '.join(settings.listen)}: {exc}\n"
            "Is another `blackmetal up` running? Choose another endpoint with -l, e.g. -l tcp/127.0.0.1:7448",
            file=sys.stderr,
        )
        return 1
    stop = stop_on_signals()
    children: list[ChildProcess] = []
    try:
        return _run(args, session, hub, children, stop)
    finally:
        _stop_children(children)
        session.close()


def _run(args: argparse.Namespace, session: zenoh.Session, hub: str, children: list[ChildProcess], stop: threading.Event) -> int:
    zargs = _child_zenoh_args(args, hub)
    prefix = args.prefix
    try:
        if args.robot:
            host, control_port, log_port = args.robot, args.control_port, args.log_port
            where = f"robot {host}:{control_port}/{log_port}"
        else:
            sim_args = ["-m", "gateway.cli", "sim", "--control-port", "0", "--log-port", "0", "--prefix", prefix, *zargs]
            if args.seed is not None:
                sim_args += ["--seed", str(args.seed)]
            sim = ChildProcess("sim", sim_args, args.verbose)
            children.append(sim)
            sim.start()
            match = sim.wait_line(r"control (\S+):(\d+), log (\S+):(\d+)", 30)
            host, control_port, log_port = match.group(1), int(match.group(2)), int(match.group(4))
            where = f"simulated robot on {host}:{control_port} (log {log_port})"
        gateway = ChildProcess(
            "gateway",
            ["-m", "gateway", "--robot", host, "--control-port", str(control_port), "--log-port", str(log_port),
             "--prefix", prefix, "--poll-hz", str(args.poll_hz), *zargs],
            args.verbose,
        )  # fmt: skip
        odometry = ChildProcess("odometry", ["-m", "odometry_service", "--prefix", prefix, *zargs], args.verbose)
        for child in (gateway, odometry):
            children.append(child)
            child.start()
        gateway.wait_line("gateway ready", 30)
        odometry.wait_line("odometry ready", 30)
    except ChildFailed as exc:
        print(f"blackmetal up: {exc}", file=sys.stderr)
        return 1
    print(f"blackmetal is up: {where}, Zenoh on {hub}, prefix {prefix}", flush=True)
    print(_drive_help(prefix, hub), flush=True)
    status = StatusLine(session, prefix, with_truth=not args.robot)
    tty = sys.stdout.isatty()
    interval = args.status_interval if tty else max(args.status_interval, 2.0)
    while not stop.wait(interval):
        for child in children:
            if child.proc.poll() is not None:
                if tty:
                    print()
                print(
                    f"blackmetal up: {child.name} exited with code {child.proc.returncode}; its last lines:\n{child.tail()}",
                    file=sys.stderr,
                    flush=True,
                )
                return 1
        line = status.render()
        if tty:
            width = os.get_terminal_size().columns if sys.stdout.isatty() else 200
            sys.stdout.write("\r\x1b[2K" + line[: max(width - 1, 20)])
            sys.stdout.flush()
        else:
            print(line, flush=True)
    if tty:
        print()
    print("blackmetal up: stopping", flush=True)
    return 0


def _stop_children(children: list[ChildProcess]) -> None:
    """Odometry and gateway first (the gateway stops the robot), then the simulator; all within 3 s."""
    deadline = time.monotonic() + STOP_BUDGET_S - 0.3
    services = [c for c in children if c.name != "sim"]
    sims = [c for c in children if c.name == "sim"]
    for group, share in ((services, 0.6), (sims, 1.0)):
        for child in group:
            child.signal(signal.SIGINT)
        group_deadline = time.monotonic() + share * max(deadline - time.monotonic(), 0.1)
        for child in group:
            try:
                child.proc.wait(max(group_deadline - time.monotonic(), 0.01))
            except subprocess.TimeoutExpired:
                pass
    for child in children:
        if child.proc.poll() is None:
            child.proc.kill()
            child.proc.wait(1)
