"""Starting up's processes and keeping them running: a gateway that dies has its robots stopped and is started again
(a navigation that dies too: the gateway's command timeout has stopped what it drove)."""

from __future__ import annotations

import argparse
import functools
import os
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from blackmetal.gateway.settings import GatewaySettings
from blackmetal.runtime.fleet import FleetRobot, load_fleet, write_fleet
from blackmetal.runtime.harness import ServiceProcess, announce_ready
from blackmetal.runtime.settings import default_of
from blackmetal.schemas import Keys

from ..stop_robot import stop_robot
from .settings import ServiceFiles, latch_args, ros2_extra
from .status import FleetStatus, StatusLine, drive_help, fleet_drive_help, goto_help
from .topology import Topology, process_count, shards

STOP_BUDGET_S = 3.0
READY_TIMEOUT_S = 30.0
#: How often the children are checked: a dead gateway's robot is stopped within about this long.
CHILD_CHECK_S = 0.05
#: A fleet's navigation commands each robot at most this often (``nav --command-hz``; 0 in a settings file: every pose):
#: 100 robots commanded at 50 Hz took the fleet gateway to a whole core and its polls down to 25-30 Hz on a 2-core host;
#: at 10 Hz they stayed at 48-50 Hz, and goals still ended within 2 mm of the simulator's truth (docs/performance.md).
FLEET_COMMAND_HZ = 5.0
#: A gateway that dies is started again (as systemd's Restart=on-failure does), at most this many times in the window (s).
MAX_RESTARTS = 5
RESTART_WINDOW_S = 60.0


@dataclass
class Launch:
    """What every child of one run shares: up's options, the settings file's parts, the Zenoh arguments; and the children."""

    args: argparse.Namespace
    files: ServiceFiles
    topology: Topology
    children: list[ServiceProcess]

    def start(self, name: str, command: list[str]) -> ServiceProcess:
        """``blackmetal COMMAND...`` with the service's part of the settings file and the Zenoh arguments, in its own session."""
        full = [*command, *self.files.args(command[0]), *self.topology.child_args()]
        child = ServiceProcess.blackmetal(name, full, echo=self.args.verbose, own_session=True)
        self.children.append(child)
        return child

    def ready(self, name: str, command: list[str]) -> dict[str, Any]:
        return self.start(name, command).wait_ready(READY_TIMEOUT_S)

    @property
    def sim_args(self) -> list[str]:
        return ["--seed", str(self.args.seed)] if self.args.seed is not None else []

    @property
    def gateway_args(self) -> list[str]:
        return [*(["--poll-hz", str(self.args.poll_hz)] if self.args.poll_hz is not None else []), *latch_args(self.args, self.files)]

    @property
    def nav_fleet_args(self) -> list[str]:
        """A fleet's navigation paced to FLEET_COMMAND_HZ, unless the settings file says otherwise."""
        return [] if self.files.sets("nav", "command_hz") else ["--command-hz", f"{FLEET_COMMAND_HZ:g}"]

    def foxglove(self, *where: str) -> str | None:
        """The Foxglove view's URL, when asked for one."""
        if not self.args.foxglove:
            return None
        return str(self.ready("foxglove", ["foxglove", *where, "--port", str(self.args.foxglove_port)])["url"])


def run_one(launch: Launch, keys: Keys, session: zenoh.Session, stop: threading.Event) -> int:
    args, prefix, hub = launch.args, keys.prefix, launch.topology.endpoint
    if args.robot:
        host, control_port, log_port = args.robot, args.control_port, args.log_port
        where = f"robot {host}:{control_port}/{log_port}"
    else:
        ready = launch.ready("sim", ["sim", "--control-port", "0", "--log-port", "0", "--prefix", prefix, *launch.sim_args])
        host, control_port, log_port = ready["host"], ready["control_port"], ready["log_port"]
        where = f"simulated robot on {host}:{control_port} (log {log_port})"
    gateway = launch.start(
        "gateway",
        ["gateway", "--robot", host, "--control-port", str(control_port), "--log-port", str(log_port), "--prefix", prefix, *launch.gateway_args],
    )  # fmt: skip
    odometry = launch.start("odometry", ["odometry", "--prefix", prefix])
    nav = launch.start("nav", ["nav", "--prefix", prefix])  # any start order: it follows the pose and health when they come
    ros2 = launch.start("ros2", ["ros2", "--flavor", args.ros2, "--prefix", prefix, *ros2_extra(args)]) if args.ros2 else None
    cmd_timeout = float(gateway.wait_ready(READY_TIMEOUT_S).get("cmd_timeout", default_of(GatewaySettings, "cmd_timeout")))
    odometry.wait_ready(READY_TIMEOUT_S)
    nav.wait_ready(READY_TIMEOUT_S)
    ros2_node = ros2.wait_ready(READY_TIMEOUT_S)["node"] if ros2 else None
    view = launch.foxglove("--prefix", prefix)
    print(f"blackmetal is up: {where}, {launch.topology.describe()}, prefix {prefix}", flush=True)
    if ros2_node:
        print(f"ROS 2: node {ros2_node} ({args.ros2}) publishes /odom, /tf, /joint_states and takes /cmd_vel, /estop", flush=True)
    if view:
        print(f"Foxglove: open a Foxglove WebSocket connection to {view} (layout: deploy/foxglove/blackmetal.layout.json)", flush=True)
    print(drive_help(keys, hub, cmd_timeout), flush=True)
    print(goto_help(keys, hub), flush=True)
    announce_ready("up", endpoint=hub, prefix=prefix, robot=host, control_port=control_port, log_port=log_port,
                   children={child.name: child.proc.pid for child in launch.children})  # fmt: skip
    status = StatusLine(session, keys, with_truth=not args.robot)

    def stop_the_robot() -> str:
        reason = stop_robot(host, control_port, timeout=2.0)
        return "the robot was sent zero velocity and NORMAL_STOP" if reason is None else reason

    return live(args, launch.children, stop, status.render, {gateway: stop_the_robot, nav: nav_gone})


def run_fleet(launch: Launch, session: zenoh.Session, stop: threading.Event, fleet_file: Path) -> int:
    """``--robots N``: one simulator for all, then the fleet gateway and odometry on the file it writes."""
    args, hub = launch.args, launch.topology.endpoint
    launch.ready("sim", ["sim", "--robots", str(args.robots), "--write-fleet", str(fleet_file), *launch.sim_args])
    robots = load_fleet(fleet_file)  # with the ports the simulator bound
    groups = shards(robots, process_count(len(robots), args.processes))
    gateways: dict[ServiceProcess, list[FleetRobot]] = {}
    odometries: list[ServiceProcess] = []
    navs: list[ServiceProcess] = []
    for k, group in enumerate(groups, 1):
        suffix = "" if len(groups) == 1 else f"-{k}"
        shard_file = fleet_file if len(groups) == 1 else fleet_file.with_name(f"fleet{suffix}.toml")
        if len(groups) > 1:
            shard_file.write_text(write_fleet(group))
        gateways[launch.start(f"gateway{suffix}", ["gateway", "--fleet", str(shard_file), *launch.gateway_args])] = group
        odometries.append(launch.start(f"odometry{suffix}", ["odometry", "--fleet", str(shard_file)]))
        navs.append(launch.start(f"nav{suffix}", ["nav", "--fleet", str(shard_file), *launch.nav_fleet_args]))
    # one ROS node per robot, /<id>/..., in one adapter process
    ros2 = launch.start("ros2", ["ros2", "--fleet", str(fleet_file), "--flavor", args.ros2, *ros2_extra(args)]) if args.ros2 else None
    announced = [gateway.wait_ready(READY_TIMEOUT_S) for gateway in gateways]
    cmd_timeout = float(announced[0].get("cmd_timeout", default_of(GatewaySettings, "cmd_timeout")))
    poll_hz = float(announced[0].get("poll_hz", default_of(GatewaySettings, "poll_hz")))
    for child in [*odometries, *navs, *([ros2] if ros2 else [])]:
        child.wait_ready(READY_TIMEOUT_S)
    view = launch.foxglove("--fleet", str(fleet_file))  # every robot in one view, /<id>/...
    shown = robots[0].prefix + (f" ... {robots[-1].prefix}" if len(robots) > 1 else "")
    n = len(gateways)
    processes = "one gateway, one odometry, one nav process" if n == 1 else f"{n} gateway, {n} odometry and {n} nav processes"
    print(
        f"blackmetal is up: {len(robots)} simulated robots {shown} on {robots[0].host} (one simulator, {processes}), {launch.topology.describe()}",
        flush=True,
    )
    if args.ros2:
        first = robots[0].id
        print(f"ROS 2 ({args.ros2}): one node per robot, /{first}/blackmetal ... with /{first}/cmd_vel, /{first}/odom, "
              f"frames {first}/odom -> {first}/base_footprint on /tf, /{first}/robot_description, services /{first}/set_estop, /{first}/reset_odometry", flush=True)  # fmt: skip
    if view:
        print(f"Foxglove: every robot in one view at {view}, topics /r1/... and /fleet/summary "
              "(layout for r1-r3: deploy/foxglove/blackmetal-fleet.layout.json)", flush=True)  # fmt: skip
    print(fleet_drive_help(robots, hub, cmd_timeout), flush=True)
    robot_rows = [[r.id, r.prefix, r.host, r.control_port, r.log_port] for r in robots]
    announce_ready("up", endpoint=hub, prefixes=[r.prefix for r in robots], robots=robot_rows,
                   children={child.name: child.proc.pid for child in launch.children})  # fmt: skip
    status = FleetStatus(session, robots, interval=_status_interval(args), poll_hz=poll_hz)
    stoppers: dict[ServiceProcess, Callable[[], str]] = {
        gateway: functools.partial(_stop_fleet, group) for gateway, group in gateways.items()
    }
    stoppers.update(dict.fromkeys(navs, nav_gone))
    return live(args, launch.children, stop, status.render, stoppers)


def nav_gone() -> str:
    """What up says of a navigation that died: nothing to stop, the gateway's command timeout ends its last command."""
    return "its goals ended; the gateway's command timeout stops a robot it drove"


def _stop_fleet(robots: list[FleetRobot]) -> str:
    """Zero velocity and NORMAL_STOP to every robot at once (their gateway is gone); what came of it, one sentence."""
    with ThreadPoolExecutor(max_workers=min(len(robots), 16), thread_name_prefix="stop-robot") as pool:
        reasons = list(pool.map(lambda r: stop_robot(r.host, r.control_port, timeout=2.0), robots))
    failed = [(robot, reason) for robot, reason in zip(robots, reasons, strict=True) if reason is not None]
    stopped = f"{len(robots) - len(failed)} of {len(robots)} robots were sent zero velocity and NORMAL_STOP"
    if not failed:
        return stopped
    robot, reason = failed[0]
    return f"{stopped}; {robot.id}: {reason}" + (f" (and {len(failed) - 1} more)" if len(failed) > 1 else "")


def _status_interval(args: argparse.Namespace) -> float:
    """Seconds between status lines: as asked on a terminal, at least 2 s into a file or a pipe."""
    return args.status_interval if sys.stdout.isatty() else max(args.status_interval, 2.0)


def live(
    args: argparse.Namespace,
    children: list[ServiceProcess],
    stop: threading.Event,
    render: Callable[[], str],
    stoppers: Mapping[ServiceProcess, Callable[[], str]],
) -> int:
    """The status line until Ctrl-C (0), or until a child dies (1, with its last lines). A gateway that dies has its
    robots stopped first (``stoppers[gateway]``) and is started again with the e-stop latch it had; so is a navigation
    (its stopper only says what became of its robots)."""
    tty = sys.stdout.isatty()
    say = functools.partial(print, file=sys.stderr, flush=True)
    interval = _status_interval(args)
    next_status = time.monotonic() + interval
    stoppers = dict(stoppers)
    restarts: deque[float] = deque()
    while not stop.wait(CHILD_CHECK_S):
        for child in list(children):
            if child.poll() is None:
                continue
            if tty:
                print()
            exited = f"blackmetal up: {child.name} exited with code {child.proc.returncode}"
            if child in stoppers:  # nobody is left to stop its robots: do it now
                say(f"blackmetal up: {child.name} gone; {stoppers[child]()}")
                now = time.monotonic()
                while restarts and restarts[0] < now - RESTART_WINDOW_S:
                    restarts.popleft()
                if len(restarts) < MAX_RESTARTS and not stop.is_set():
                    restarts.append(now)
                    say(f"{exited}; starting it again ({len(restarts)} of at most {MAX_RESTARTS} restarts in {RESTART_WINDOW_S:g} s); "
                        f"its last lines:\n{child.tail()}")  # fmt: skip
                    child.stop(timeout=1.0)  # reaped, its pipes closed
                    again = ServiceProcess(child.name, child.args, echo=child.echo, own_session=True)
                    children[children.index(child)] = again
                    stoppers[again] = stoppers.pop(child)
                    say(f"blackmetal up: {child.name} started again (pid {again.proc.pid})")
                    continue
            say(f"{exited}; its last lines:\n{child.tail()}")
            return 1
        if time.monotonic() < next_status:
            continue
        next_status += interval
        line = render()
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
