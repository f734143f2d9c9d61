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
import sys
import threading
import time

import zenoh

from blackmetal.foxglove.settings import FoxgloveSettings
from blackmetal.ros2.naming import Flavor
from blackmetal.ros2.settings import Ros2Settings
from blackmetal.runtime.harness import ChildFailed, ServiceProcess, announce_ready, stop_in_order
from blackmetal.runtime.settings import default_of, read_settings_file
from blackmetal.runtime.signals import stop_on_signals
from blackmetal.runtime.zenoh_setup import add_zenoh_arguments, open_session, zenoh_settings
from gateway.settings import GatewaySettings
from schemas import DEFAULT_PREFIX, ErrorReport, GatewayHealth, Keys, Pose, require_extra

from .client import Latest, tool
from .stop_robot import stop_robot

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
STOP_BUDGET_S = 3.0
READY_TIMEOUT_S = 30.0
#: How often the children are checked: a dead gateway's robot is stopped within about this long.
CHILD_CHECK_S = 0.05


def _child_zenoh_args(args: argparse.Namespace, hub: str) -> list[str]:
    """Children are clients of our session, which routes between them and the tools (plus any routers given with -e)."""
    out = ["-m", "client", "-e", hub]
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


def python_snippet(keys: Keys, endpoint: str) -> str:
    """A shell command that drives the robot for 3 s from plain Python (no single quotes inside)."""
    code = (
        "import zenoh, time; c = zenoh.Config(); "
        f'c.insert_json5("connect/endpoints", "[\\"{endpoint}\\"]"); s = zenoh.open(c); '
        f'[(s.put("{keys.cmd_vel}", "{{\\"linear\\":{{\\"x\\":0.2}},\\"angular\\":{{\\"z\\":0.5}}}}"), time.sleep(0.1)) '
        "for _ in range(30)]; s.close()"
    )
    return f"python3 -c '{code}'"


def _drive_help(keys: Keys, endpoint: str) -> str:
    return "\n".join(
        [
            "Drive it from any Zenoh client (commands time out after 0.5 s: publish at 5 Hz or more):",
            f"  blackmetal teleop -e {endpoint}",
            f"  {python_snippet(keys, endpoint)}",
            f'  z_put -e {endpoint} -k {keys.cmd_vel} -p \'{{"linear":{{"x":0.2}}}}\'   # zenoh\'s own CLI, if installed',
            f"Watch it:  blackmetal watch -e {endpoint}    Pose:  z_get -e {endpoint} -s {keys.pose}",
            "Ctrl-C stops everything.",
        ]
    )


class StatusLine:
    """Subscriptions for the live one-line status."""

    def __init__(self, session: zenoh.Session, keys: Keys, with_truth: bool) -> None:
        self.health = Latest(session, keys.health, GatewayHealth)
        self.pose = Latest(session, keys.pose, Pose)
        self.truth = Latest(session, keys.sim_truth, Pose) if with_truth else None
        self.errors = Latest(session, keys.errors, ErrorReport)
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
    """up's own options; the defaults of those it passes on are the services' settings defaults."""
    control_port, log_port = default_of(GatewaySettings, "control_port"), default_of(GatewaySettings, "log_port")
    parser = parser or argparse.ArgumentParser(prog="blackmetal up", description=__doc__)
    parser.add_argument("--robot", metavar="HOST", help="drive a real robot at HOST instead of the simulator")
    parser.add_argument("--control-port", type=int, default=control_port, help=f"robot control port with --robot (default {control_port})")
    parser.add_argument("--log-port", type=int, default=log_port, help=f"robot log port with --robot (default {log_port})")
    parser.add_argument("--prefix", default=DEFAULT_PREFIX, help=f"key-expression prefix (default {DEFAULT_PREFIX})")
    parser.add_argument(
        "--poll-hz",
        type=float,
        default=None,  # not given: the gateway's own default (or the --settings file) applies
        help=f"wheel polls per second (default {default_of(GatewaySettings, 'poll_hz'):g})",
    )
    parser.add_argument("--seed", type=int, help="simulator fault seed")
    parser.add_argument(
        "--settings", metavar="FILE", help="settings file for the gateway and the odometry (e.g. from blackmetal calibrate)"
    )
    parser.add_argument("--status-interval", type=float, default=0.5, help="seconds between status updates")
    flavor = default_of(Ros2Settings, "flavor")
    others = " or ".join(f.value for f in Flavor if f.value != flavor)
    parser.add_argument(
        "--ros2",
        nargs="?",
        const=flavor,
        choices=[f.value for f in Flavor],
        metavar="FLAVOR",
        help=f"also run the ROS 2 adapter (blackmetal ros2), {flavor} (default) or {others}",
    )
    foxglove_port = default_of(FoxgloveSettings, "port")
    parser.add_argument("--foxglove", action="store_true", help="also serve a live Foxglove view (blackmetal foxglove)")
    parser.add_argument("--foxglove-port", type=int, default=foxglove_port, help=f"its WebSocket port (default {foxglove_port})")
    parser.add_argument("-v", "--verbose", action="store_true", help="show the services' own log lines")
    add_zenoh_arguments(parser)
    return parser


@tool("up")
def run(args: argparse.Namespace) -> int:
    """Exit 2 for a setting up cannot use, 1 when Zenoh or a child fails; one sentence each."""
    keys = Keys(args.prefix)
    if args.ros2:
        require_extra("blackmetal up --ros2", "ros2", "rosbags")
    if args.foxglove:
        require_extra("blackmetal up --foxglove", "foxglove", "foxglove")
    if args.settings:
        read_settings_file(args.settings)  # a missing or broken file: one sentence now, not two failing children
    settings = zenoh_settings(args)
    if not settings.listen:
        settings.listen = [DEFAULT_LISTEN]
    hub = _hub_endpoint(settings.listen[0])
    session = open_session(settings)
    stop = stop_on_signals()
    children: list[ServiceProcess] = []
    try:
        return _run(args, keys, session, hub, children, stop)
    finally:
        # odometry and gateway first (the gateway stops the robot), then the simulator
        stop_in_order([[c for c in children if c.name != "sim"], [c for c in children if c.name == "sim"]], STOP_BUDGET_S - 0.3)
        session.close()


def _start(children: list[ServiceProcess], name: str, command: list[str], verbose: bool) -> ServiceProcess:
    child = ServiceProcess.blackmetal(name, command, echo=verbose, own_session=True)
    children.append(child)
    return child


def _run(
    args: argparse.Namespace,
    keys: Keys,
    session: zenoh.Session,
    hub: str,
    children: list[ServiceProcess],
    stop: threading.Event,
) -> int:
    zargs = _child_zenoh_args(args, hub)
    settings_args = ["--settings", os.path.abspath(args.settings)] if args.settings else []
    poll_args = ["--poll-hz", str(args.poll_hz)] if args.poll_hz is not None else []
    prefix = keys.prefix
    try:
        if args.robot:
            host, control_port, log_port = args.robot, args.control_port, args.log_port
            where = f"robot {host}:{control_port}/{log_port}"
        else:
            sim_args = ["sim", "--control-port", "0", "--log-port", "0", "--prefix", prefix, *zargs]
            if args.seed is not None:
                sim_args += ["--seed", str(args.seed)]
            ready = _start(children, "sim", sim_args, args.verbose).wait_ready(READY_TIMEOUT_S)
            host, control_port, log_port = ready["host"], ready["control_port"], ready["log_port"]
            where = f"simulated robot on {host}:{control_port} (log {log_port})"
        gateway = _start(
            children,
            "gateway",
            ["gateway", "--robot", host, "--control-port", str(control_port), "--log-port", str(log_port),
             "--prefix", prefix, *poll_args, *settings_args, *zargs],
            args.verbose,
        )  # fmt: skip
        odometry = _start(children, "odometry", ["odometry", "--prefix", prefix, *settings_args, *zargs], args.verbose)
        ros2 = _start(children, "ros2", ["ros2", "--flavor", args.ros2, "--prefix", prefix, *zargs], args.verbose) if args.ros2 else None
        gateway.wait_ready(READY_TIMEOUT_S)
        odometry.wait_ready(READY_TIMEOUT_S)
        ros2_node = ros2.wait_ready(READY_TIMEOUT_S)["node"] if ros2 else None
        view = None
        if args.foxglove:
            view_args = ["foxglove", "--prefix", prefix, "--port", str(args.foxglove_port), *zargs]
            view = _start(children, "foxglove", view_args, args.verbose).wait_ready(READY_TIMEOUT_S)["url"]
    except ChildFailed as exc:
        print(f"blackmetal up: {exc}", file=sys.stderr)
        return 1
    print(f"blackmetal is up: {where}, Zenoh on {hub}, prefix {prefix}", flush=True)
    if ros2_node:
        print(f"ROS 2: node {ros2_node} ({args.ros2}) publishes /odom, /tf, /joint_states and takes /cmd_vel, /estop", flush=True)
    if view:
        print(f"Foxglove: open a Foxglove WebSocket connection to {view} (layout: deploy/foxglove/blackmetal.layout.json)", flush=True)
    print(_drive_help(keys, hub), flush=True)
    announce_ready(
        "up",
        endpoint=hub,
        prefix=prefix,
        robot=host,
        control_port=control_port,
        log_port=log_port,
        children={child.name: child.proc.pid for child in children},
    )
    status = StatusLine(session, keys, with_truth=not args.robot)
    tty = sys.stdout.isatty()
    interval = args.status_interval if tty else max(args.status_interval, 2.0)
    next_status = time.monotonic() + interval
    while not stop.wait(CHILD_CHECK_S):
        for child in children:
            if child.poll() is not None:
                if tty:
                    print()
                if child is gateway:  # nobody is left to stop the robot: do it now
                    reason = stop_robot(host, control_port, timeout=2.0)
                    outcome = "the robot was sent zero velocity and NORMAL_STOP" if reason is None else reason
                    print(f"blackmetal up: gateway gone; {outcome}", file=sys.stderr, flush=True)
                print(
                    f"blackmetal up: {child.name} exited with code {child.proc.returncode}; its last lines:\n{child.tail()}",
                    file=sys.stderr,
                    flush=True,
                )
                return 1
        if time.monotonic() < next_status:
            continue
        next_status += interval
        line = status.render()
        if tty:
            width = os.get_terminal_size().columns
            sys.stdout.write("\r\x1b[2K" + line[: max(width - 1, 20)])
            sys.stdout.flush()
        else:
            print(line, flush=True)
    if tty:
        print()
    print("blackmetal up: stopping", flush=True)
    return 0
