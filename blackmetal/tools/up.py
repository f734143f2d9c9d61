"""``blackmetal up``: the simulated robot, the gateway and the odometry service in one command.

Each runs as its own process; this one holds the Zenoh endpoint that clients
connect to (``tcp/127.0.0.1:7447`` unless ``-l`` says otherwise), prints how
to drive the robot, then a live one-line status. Given a router with ``-e``
and no ``-l`` (ROS 2's ``rmw_zenohd``, a fleet's router), it holds no
endpoint: every process of the demo is a client of that router. Ctrl-C stops
everything within 3 s; a child that dies is reported with its last lines.

With ``--robots N``: a fleet of N simulated robots r1 ... rN under
``fleet/<id>``, in three processes whatever N (``sim --robots N``,
``gateway --fleet``, ``odometry --fleet``, sharing the fleet file the
simulator writes), and one live status line for the whole fleet.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import os
import statistics
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import zenoh

from blackmetal.foxglove.settings import FoxgloveSettings
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.odometry_service.settings import OdometrySettings
from blackmetal.robot_model import RESIDUAL_LINE
from blackmetal.ros2.naming import Flavor, parse_distros
from blackmetal.ros2.settings import Ros2Settings
from blackmetal.runtime.fleet import FleetRobot, load_fleet, write_fleet
from blackmetal.runtime.harness import ChildFailed, ServiceProcess, announce_ready, stop_in_order
from blackmetal.runtime.settings import default_of, load_settings, read_settings_file
from blackmetal.runtime.signals import stop_on_signals
from blackmetal.runtime.zenoh_entities import undeclare
from blackmetal.runtime.zenoh_setup import DEFAULT_ENDPOINT, ZenohSettings, add_zenoh_arguments, open_when_reachable, zenoh_settings
from blackmetal.schemas import (
    ANY_GATEWAY_ALIVE,
    DEFAULT_PREFIX,
    ConfigError,
    ErrorReport,
    GatewayHealth,
    Keys,
    PayloadError,
    Pose,
    decode,
    require_extra,
    to_bytes,
    validate_prefix,
)
from blackmetal.sim.settings import SimSettings

from .client import Latest, tool
from .stop_robot import stop_robot

DEFAULT_LISTEN = DEFAULT_ENDPOINT
STOP_BUDGET_S = 3.0
#: Robots one gateway (or odometry) process carries at 50 Hz with room to spare: the fleet gateway took 0.66 cores for
#: 100 robots on the reference machine; past this, --robots spreads them over more processes, one per core at most.
ROBOTS_PER_PROCESS = 150
#: The status line says the fleet is behind when its median poll rate is below this fraction of the asked rate.
BEHIND_RATIO = 0.9
READY_TIMEOUT_S = 30.0
#: How often the children are checked: a dead gateway's robot is stopped within about this long.
CHILD_CHECK_S = 0.05
#: A gateway that dies is started again (as systemd's Restart=on-failure does), at most this many times in the window (s).
MAX_RESTARTS = 5
RESTART_WINDOW_S = 60.0
#: A fleet robot's health older than this (s; the gateway reports every second) counts as missing.
HEALTH_STALE_S = 3.0
#: The fleet's pose rates are measured over one status interval this often (s).
POSE_SAMPLE_EVERY_S = 5.0
#: A robot's poses per second at most (a pose per poll; the gateway polls at most 200 Hz): the sampling ring's size.
POSES_PER_S_AT_MOST = 200
#: The fleet status line names at most this many robots per item, then "+k".
NAMED_AT_MOST = 5


#: The services ``up --settings FILE`` can configure, by section name.
SERVICES: dict[str, type] = {
    "gateway": GatewaySettings,
    "odometry": OdometrySettings,
    "sim": SimSettings,
    "ros2": Ros2Settings,
    "foxglove": FoxgloveSettings,
}
#: Keys outside a section go to every one of these that has the setting. Not to the simulator: its wheel
#: settings are the true robot's, not a calibration's; a key only the simulator knows still goes to it.
SHARED = ("gateway", "odometry", "ros2", "foxglove")
#: What up decides itself, whatever a settings file says: the robot (simulator or --robot) and the Zenoh endpoints.
UP_DECIDES = frozenset({"robot", "control_port", "log_port"}) | {
    f.name for f in dataclasses.fields(ZenohSettings) if f.metadata.get("cli", True)
}


def _setting_names(cls: type) -> set[str]:
    return {f.name for f in dataclasses.fields(cls) if f.name != "zenoh"}


def split_settings(path: str) -> tuple[dict[str, dict[str, Any]], list[str]]:
    """A settings file with any service's keys -> each service's own keys, and the keys up decides itself.

    Keys at the top level go to every service (gateway, odometry, ROS 2
    adapter, Foxglove view) that has the setting, or to the simulator if
    only it has it; ``[gateway]``, ``[odometry]``, ``[sim]``, ``[ros2]`` and
    ``[foxglove]`` sections go to that service alone. A key no service has
    is a ConfigError naming it.
    """
    data = read_settings_file(path)
    own: dict[str, dict[str, Any]] = {name: {} for name in SERVICES}
    unknown: list[str] = []
    decided: list[str] = []

    def place(key: str, value: Any, names: tuple[str, ...], label: str) -> None:
        if key in UP_DECIDES:
            decided.append(label)
            return
        takers = [name for name in names if key in _setting_names(SERVICES[name])]
        if not takers and names == SHARED and key in _setting_names(SimSettings):
            takers = ["sim"]
        if not takers:
            unknown.append(label)
        for name in takers:
            own[name][key] = value

    for key, value in data.items():
        if key in SERVICES and isinstance(value, dict):
            for sub, sub_value in value.items():
                sub = str(sub).replace("-", "_")
                place(sub, sub_value, (key,), f"{key}.{sub}")
        else:
            place(key, value, SHARED, key)
    if unknown:
        raise ConfigError(
            f"settings file {path}: unknown settings {sorted(unknown)}: no service ({', '.join(SERVICES)}) has them; "
            "`blackmetal SERVICE --help` lists each one's, and a [SERVICE] section gives a key to one service only"
        )
    return own, decided


class ServiceFiles:
    """Each service's part of ``up --settings FILE``, written as its own JSON file for its ``--settings``."""

    def __init__(self, path: str | None, services: list[str]) -> None:
        self._dir: tempfile.TemporaryDirectory[str] | None = None
        self.files: dict[str, str] = {}
        self.prefix: str | None = None
        self.decided: list[str] = []
        if not path:
            return
        own, self.decided = split_settings(path)
        prefixes = {str(values["prefix"]) for values in own.values() if "prefix" in values}
        if len(prefixes) > 1:
            raise ConfigError(f"settings file {path}: one demo has one prefix, got {sorted(prefixes)}")
        self.prefix = prefixes.pop() if prefixes else None
        self._dir = tempfile.TemporaryDirectory(prefix="blackmetal-up-")
        for name in services:
            if not own[name]:
                continue
            file = Path(self._dir.name) / f"{name}.json"
            file.write_text(json.dumps(own[name], default=str))
            load_settings(SERVICES[name], {}, settings_file=str(file))  # a bad value: one sentence now, not a failed child
            self.files[name] = str(file)

    def args(self, name: str) -> list[str]:
        return ["--settings", self.files[name]] if name in self.files else []

    def run_dir(self) -> str:
        """This run's own folder (removed when up ends): the state of the simulated robots it starts."""
        if self._dir is None:
            self._dir = tempfile.TemporaryDirectory(prefix="blackmetal-up-")
        return self._dir.name

    def close(self) -> None:
        if self._dir is not None:
            self._dir.cleanup()


class Topology:
    """Where up's session and its children meet.

    No flags or ``-l``: up listens (a hub) and the children are its clients.
    ``-e ROUTER`` without ``-l``: no hub; up and every child are clients of
    the router, which routes for clients (ROS 2's ``rmw_zenohd`` does not
    route between peers, so a hub peer of it would never reach a ROS node).
    ``-l`` and ``-e``: up's hub is a Zenoh router connected to those routers,
    which route to it as to any router.
    """

    def __init__(self, args: argparse.Namespace) -> None:
        self.settings = zenoh_settings(args)
        self.routers = list(self.settings.connect)
        self.hub = bool(self.settings.listen) or not self.routers
        if self.hub:
            if not self.settings.listen:
                self.settings.listen = [DEFAULT_LISTEN]
            if self.routers and self.settings.mode is None:
                self.settings.mode = "router"
            self.endpoint = _hub_endpoint(self.settings.listen[0])
            self.child_endpoints = [self.endpoint]
        else:
            self.endpoint = self.routers[0]
            self.child_endpoints = self.routers
        self.config = args.config

    def child_args(self) -> list[str]:
        out = ["-m", "client"]
        for endpoint in self.child_endpoints:
            out += ["-e", endpoint]
        if self.config:
            out += ["-c", self.config]
        return out

    def describe(self) -> str:
        if not self.hub:
            return f"Zenoh via the router at {self.endpoint} (every process its client)"
        return f"Zenoh on {self.endpoint}" + (f" (a router, connected to {', '.join(self.routers)})" if self.routers else "")


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


def _timeout_advice(cmd_timeout: float) -> str:
    """How often a client must publish, given the gateway's command timeout (s; 0: none)."""
    if not cmd_timeout > 0:
        return "commands never time out: publish a zero to stop"
    return f"commands time out after {cmd_timeout:g} s: publish at {math.ceil(2.5 / cmd_timeout):g} Hz or more"


def _drive_help(keys: Keys, endpoint: str, cmd_timeout: float = 0.5) -> str:
    return "\n".join(
        [
            f"Drive it from any Zenoh client ({_timeout_advice(cmd_timeout)}):",
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
            reason = h.control.reason or h.log.reason  # why the robot cannot be reached, as the gateway knows it
            if reason and h.control.state != "connected":
                parts.append(reason)
            parts.append(f"poll {h.poll_hz:.0f} Hz")
            if h.estop:
                parts.append("E-STOP")
            if h.active_source:
                parts.append(f"{h.active_source} drives")
            elif h.cmd_timeout_active:
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


def _named(ids: list[str]) -> str:
    """``r1, r3`` or, past NAMED_AT_MOST, ``r1, r2, r3, r4, r5 +7``."""
    shown = ", ".join(ids[:NAMED_AT_MOST])
    return shown + (f" +{len(ids) - NAMED_AT_MOST}" if len(ids) > NAMED_AT_MOST else "")


class PoseSampler:
    """Each robot's poses per second, measured over one status interval every :data:`POSE_SAMPLE_EVERY_S`.

    Counting every pose costs the status line more than the router's own work
    (0.1 cores at 100 robots: 5,000 poses a second delivered into ``up``'s
    session, even into a ring): so one subscriber on ``**/pose`` is declared
    for one interval, its ring emptied and counted at the next line, and
    undeclared. The line shows the rates of the last such window.
    """

    def __init__(self, session: zenoh.Session, prefixes: list[str], interval: float) -> None:
        self.session = session
        self.prefixes = set(prefixes)
        self.capacity = max(1024, math.ceil(POSES_PER_S_AT_MOST * len(prefixes) * interval * 1.5))
        self.rates: dict[str, float] | None = None  # None: not measured yet
        self._subscriber: Any = None
        self._since = 0.0
        self._next = time.monotonic()

    def tick(self, now: float) -> None:
        """At each status line: end a window that is open (its rates), or open one when it is due."""
        if self._subscriber is not None:
            counts = dict.fromkeys(self.prefixes, 0)
            while (sample := self._subscriber.try_recv()) is not None:
                prefix = str(sample.key_expr).removesuffix("/pose")
                if prefix in counts:
                    counts[prefix] += 1
            undeclare(self._subscriber)
            self._subscriber = None
            elapsed = max(now - self._since, 1e-6)
            self.rates = {prefix: count / elapsed for prefix, count in counts.items()}
            self._next = now + POSE_SAMPLE_EVERY_S
        elif now >= self._next:
            self._subscriber = self.session.declare_subscriber("**/pose", zenoh.handlers.RingChannel(self.capacity))
            self._since = now


class FleetStatus:
    """Subscriptions for the fleet's one-line status: gateways alive, each robot's health, poses and errors.

    The callbacks only store (a decoded health, a count); :meth:`render` does
    the arithmetic. Poses are sampled, not followed (:class:`PoseSampler`).
    """

    def __init__(self, session: zenoh.Session, robots: list[FleetRobot], interval: float = 2.0, poll_hz: float = 50.0) -> None:
        """``interval``: the time between two :meth:`render` calls; ``poll_hz``: the rate the gateways were asked for."""
        self.robots = robots
        self.poll_hz = poll_hz
        self.alive: set[str] = set()
        self.health: dict[str, tuple[GatewayHealth, float]] = {}
        self.errors = dict.fromkeys((r.prefix for r in robots), 0)
        self.poses = PoseSampler(session, [r.prefix for r in robots], interval)
        #: Robots seen with both links connected since the start: before that, a robot is "connecting", not "down".
        self._ever_linked: set[str] = set()
        prefixes = {r.prefix for r in robots}
        self._subs: list[Any] = [
            session.liveliness().declare_subscriber(ANY_GATEWAY_ALIVE, lambda s: self._on_token(s, prefixes), history=True)
        ]
        for robot in robots:
            keys = Keys(robot.prefix)
            self._subs += [
                session.declare_subscriber(keys.health, functools.partial(self._on_health, robot.prefix)),
                session.declare_subscriber(keys.errors, functools.partial(self._count, self.errors, robot.prefix)),
            ]

    def _on_token(self, sample: zenoh.Sample, prefixes: set[str]) -> None:
        prefix = Keys.prefix_of_gateway_token(str(sample.key_expr))
        if prefix not in prefixes:
            return
        if sample.kind == zenoh.SampleKind.PUT:
            self.alive.add(prefix)
        else:
            self.alive.discard(prefix)

    def _on_health(self, prefix: str, sample: zenoh.Sample) -> None:
        try:
            self.health[prefix] = (decode(GatewayHealth, to_bytes(sample.payload)), time.monotonic())
        except PayloadError:  # a malformed report: the previous one stands until it goes stale
            pass

    @staticmethod
    def _count(counts: dict[str, int], prefix: str, _sample: zenoh.Sample) -> None:
        counts[prefix] += 1

    def render(self) -> str:
        now = time.monotonic()
        self.poses.tick(now)
        rates = None if self.poses.rates is None else [self.poses.rates[r.prefix] for r in self.robots]
        fresh = {p: h for p, (h, at) in list(self.health.items()) if now - at <= HEALTH_STALE_S}
        polls = [fresh[r.prefix].poll_hz if r.prefix in fresh else 0.0 for r in self.robots]
        count = len(self.robots)
        parts = [f"robots {len(self.alive)}/{count} up"]
        linked = {r.prefix for r in self.robots if r.prefix in fresh and _links(fresh[r.prefix]) == "connected/connected"}
        self._ever_linked |= linked
        # a robot not yet up since the start is connecting, no fault; one that was up and is not is missing or down
        connecting = [r.id for r in self.robots if r.prefix not in linked and r.prefix not in self._ever_linked]
        missing = [r.id for r in self.robots if r.prefix not in fresh and r.prefix in self._ever_linked]
        down = [r.id for r in self.robots if r.prefix in fresh and r.prefix not in linked and r.prefix in self._ever_linked]
        if connecting:
            parts.append(f"connecting {len(connecting)}: {_named(connecting)}")
        if missing:
            parts.append(f"no health {len(missing)}: {_named(missing)}")
        if down:
            first = fresh[next(r.prefix for r in self.robots if r.id == down[0])]
            reason = first.control.reason or first.log.reason
            parts.append(f"link down {len(down)}: {_named(down)}" + (f" ({down[0]}: {reason})" if reason else ""))
        parts.append(f"poll min {min(polls):.0f} median {statistics.median(polls):.0f} Hz")
        linked_polls = [fresh[r.prefix].poll_hz for r in self.robots if r.prefix in linked]
        if linked_polls and statistics.median(linked_polls) < BEHIND_RATIO * self.poll_hz:
            parts.append(f"BEHIND {self.poll_hz:g} Hz: the host is short of CPU (commands and e-stops keep their latency)")
        if rates is None:
            parts.append("poses/s measuring")
        else:
            parts.append(f"poses/s min {min(rates):.0f} median {statistics.median(rates):.0f}")
        stopped = [r.id for r in self.robots if r.prefix in fresh and fresh[r.prefix].estop]
        parts.append(f"E-STOP {len(stopped)}/{count}: {_named(stopped)}" if stopped else f"e-stop 0/{count}")
        driving = [f"{r.id} ({fresh[r.prefix].active_source})" for r in self.robots if r.prefix in fresh and fresh[r.prefix].active_source]
        if driving:
            parts.append(f"driving {_named(driving)}")
        erring = [r.id for r in self.robots if self.errors[r.prefix]]
        if erring:
            parts.append(f"errors {sum(self.errors.values())}: {_named(erring)}")
        return " | ".join(parts)


def _links(health: GatewayHealth) -> str:
    return f"{health.control.state}/{health.log.state}"


def _fleet_drive_help(robots: list[FleetRobot], endpoint: str, cmd_timeout: float) -> str:
    first = robots[0].prefix
    return "\n".join(
        [
            f"Drive one robot from any Zenoh client, by its prefix ({first} ... {robots[-1].prefix}; {_timeout_advice(cmd_timeout)}):",
            f"  blackmetal teleop --prefix {first} -e {endpoint}",
            f"  {python_snippet(Keys(first), endpoint)}",
            f"Watch one:  blackmetal watch --prefix {first} -e {endpoint}    All:  blackmetal robots -e {endpoint}",
            f"Stop one:   blackmetal estop on --prefix {first} -e {endpoint}",
            "Ctrl-C stops everything.",
        ]
    )


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    """up's own options; the defaults of those it passes on are the services' settings defaults."""
    control_port, log_port = default_of(GatewaySettings, "control_port"), default_of(GatewaySettings, "log_port")
    parser = parser or argparse.ArgumentParser(prog="blackmetal up", description=__doc__)
    parser.add_argument("--robot", metavar="HOST", help="drive a real robot at HOST instead of the simulator")
    parser.add_argument(
        "--robots",
        type=int,
        metavar="N",
        help="a fleet: N simulated robots r1..rN under fleet/<id>, in one simulator, one gateway and one odometry "
        "process (--fleet), with one status line for all",
    )
    parser.add_argument(
        "--processes",
        type=int,
        metavar="K",
        help=f"with --robots: spread the robots over K gateway and K odometry processes (default: one per "
        f"{ROBOTS_PER_PROCESS} robots, at most one per core)",
    )
    parser.add_argument("--control-port", type=int, default=control_port, help=f"robot control port with --robot (default {control_port})")
    parser.add_argument("--log-port", type=int, default=log_port, help=f"robot log port with --robot (default {log_port})")
    parser.add_argument(
        "--prefix", default=None, help=f"key-expression prefix (default: the --settings file's prefix, else {DEFAULT_PREFIX})"
    )
    parser.add_argument(
        "--poll-hz",
        type=float,
        default=None,  # not given: the gateway's own default (or the --settings file) applies
        help=f"wheel polls per second (default {default_of(GatewaySettings, 'poll_hz'):g})",
    )
    parser.add_argument("--seed", type=int, help="simulator fault seed")
    parser.add_argument(
        "--settings",
        metavar="FILE",
        help="settings file with any service's keys, each service takes its own (e.g. from blackmetal calibrate); "
        "or sections [gateway], [odometry], [sim], [ros2], [foxglove]",
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
    parser.add_argument(
        "--distro",
        metavar="NAME[,NAME]",
        help="with --ros2: the ROS 2 distro(s) whose rmw_zenoh formats the adapter speaks, humble, jazzy, kilted, lyrical "
        "or rolling, or several comma-separated, one node each (default: ROS_DISTRO when set, else jazzy)",
    )
    foxglove_port = default_of(FoxgloveSettings, "port")
    parser.add_argument("--foxglove", action="store_true", help="also serve a live Foxglove view (blackmetal foxglove)")
    parser.add_argument("--foxglove-port", type=int, default=foxglove_port, help=f"its WebSocket port (default {foxglove_port})")
    parser.add_argument("-v", "--verbose", action="store_true", help="show the services' own log lines")
    add_zenoh_arguments(parser)
    return parser


def ros2_extra(args: argparse.Namespace) -> list[str]:
    """What up passes the ROS 2 adapter besides its settings: ``--distro``, and ``--calibration FILE`` when the
    ``--settings`` file is a calibration with residuals (they are comments, which the settings split does not carry)."""
    extra = ["--distro", args.distro] if args.distro else []
    if args.settings and Path(args.settings).suffix == ".toml":
        try:
            text = Path(args.settings).read_text()
        except OSError:
            return extra  # ServiceFiles has said what is wrong with it
        if any(line.startswith(RESIDUAL_LINE) for line in text.splitlines()):
            extra += ["--calibration", str(args.settings)]
    return extra


def check_fleet_options(args: argparse.Namespace) -> None:
    """ConfigError, one sentence, for an option that makes no sense with ``--robots N``."""
    count = args.robots
    if count < 1:
        raise ConfigError(f"--robots needs at least 1 robot, got {count}")
    if args.robot:
        raise ConfigError("--robot HOST drives one real robot and --robots N simulates N: give one or the other "
                          "(real robots of a fleet: a fleet file for `blackmetal gateway --fleet FILE`)")  # fmt: skip
    if args.prefix:
        raise ConfigError(f"--prefix does not go with --robots: the fleet's prefixes are fleet/r1 ... fleet/r{count}")
    if args.processes is not None and not 1 <= args.processes <= count:
        raise ConfigError(f"--processes {args.processes}: give 1 to {count} (the robots of --robots {count} are spread over them)")


def process_count(robots: int, asked: int | None, cores: int | None = None) -> int:
    """How many gateway (and odometry) processes carry ``robots``: as asked, else one per ROBOTS_PER_PROCESS robots,
    at most one per core."""
    if asked is not None:
        return asked
    return max(1, min(cores or os.cpu_count() or 1, math.ceil(robots / ROBOTS_PER_PROCESS)))


def shards(robots: list[FleetRobot], count: int) -> list[list[FleetRobot]]:
    """``robots`` in ``count`` contiguous groups of near-equal size (r1..r50, r51..r100)."""
    size, extra = divmod(len(robots), count)
    out, start = [], 0
    for k in range(count):
        end = start + size + (1 if k < extra else 0)
        out.append(robots[start:end])
        start = end
    return out


@tool("up")
def run(args: argparse.Namespace) -> int:
    """Exit 2 for a setting up cannot use, 1 when Zenoh or a child fails; one sentence each."""
    fleet = args.robots is not None
    if fleet:
        check_fleet_options(args)
    elif args.processes is not None:
        raise ConfigError("--processes spreads a fleet of --robots N: give --robots as well")
    if args.ros2:
        require_extra("blackmetal up --ros2", "ros2", "rosbags")
    if args.distro is not None:
        if not args.ros2:
            raise ConfigError("--distro is for the ROS 2 adapter: give --ros2 as well")
        parse_distros(args.distro)
    if args.foxglove:
        require_extra("blackmetal up --foxglove", "foxglove", "foxglove")
    services = ["gateway", "odometry", *([] if args.robot else ["sim"]), *(["ros2"] if args.ros2 else []),
                *(["foxglove"] if args.foxglove else [])]  # fmt: skip
    files = ServiceFiles(args.settings, services)  # a missing or broken file: one sentence now, not failing children
    try:
        if files.decided:
            print(
                f"blackmetal up: {args.settings}: {', '.join(files.decided)} left to up's own options "
                "(--robot, --control-port, --log-port, -l, -e, -c)",
                flush=True,
            )
        if fleet and files.prefix:
            raise ConfigError(f"settings file {args.settings}: prefix {files.prefix!r} does not go with --robots (fleet/r1 ...)")
        keys = Keys(validate_prefix(args.prefix or files.prefix or DEFAULT_PREFIX))
        topology = Topology(args)
        stop = stop_on_signals()
        session = open_when_reachable(topology.settings, stop, "up")
        if session is None:
            return 0  # Ctrl-C while waiting for the router
        children: list[ServiceProcess] = []
        try:
            if fleet:
                with tempfile.TemporaryDirectory(prefix="blackmetal-fleet-") as workdir:
                    return _run_fleet(args, session, topology, files, children, stop, Path(workdir) / "fleet.toml")
            return _run(args, keys, session, topology, files, children, stop)
        finally:
            # odometry and gateway first (the gateway stops the robot), then the simulator
            stop_in_order([[c for c in children if c.name != "sim"], [c for c in children if c.name == "sim"]], STOP_BUDGET_S - 0.3)
            session.close()
    finally:
        files.close()


def latch_args(args: argparse.Namespace, files: ServiceFiles) -> list[str]:
    """Where the gateway keeps its e-stop latch: for up's own simulated robots, in this run's folder, released at
    first (they are new, as the latch is); for a real robot (``--robot``), the gateway's default (``--state-dir``), so
    that a latch engaged before a crash, a restart of up or a reboot is still engaged."""
    if args.robot:
        return []
    return ["--state-dir", files.run_dir(), "--unsafe-start-released"]


def _start(children: list[ServiceProcess], name: str, command: list[str], verbose: bool) -> ServiceProcess:
    child = ServiceProcess.blackmetal(name, command, echo=verbose, own_session=True)
    children.append(child)
    return child


def _run(
    args: argparse.Namespace,
    keys: Keys,
    session: zenoh.Session,
    topology: Topology,
    files: ServiceFiles,
    children: list[ServiceProcess],
    stop: threading.Event,
) -> int:
    zargs = topology.child_args()
    hub = topology.endpoint
    poll_args = ["--poll-hz", str(args.poll_hz)] if args.poll_hz is not None else []
    prefix = keys.prefix
    try:
        if args.robot:
            host, control_port, log_port = args.robot, args.control_port, args.log_port
            where = f"robot {host}:{control_port}/{log_port}"
        else:
            sim_args = ["sim", "--control-port", "0", "--log-port", "0", "--prefix", prefix, *files.args("sim"), *zargs]
            if args.seed is not None:
                sim_args += ["--seed", str(args.seed)]
            ready = _start(children, "sim", sim_args, args.verbose).wait_ready(READY_TIMEOUT_S)
            host, control_port, log_port = ready["host"], ready["control_port"], ready["log_port"]
            where = f"simulated robot on {host}:{control_port} (log {log_port})"
        gateway = _start(
            children,
            "gateway",
            ["gateway", "--robot", host, "--control-port", str(control_port), "--log-port", str(log_port),
             "--prefix", prefix, *poll_args, *latch_args(args, files), *files.args("gateway"), *zargs],
            args.verbose,
        )  # fmt: skip
        odometry = _start(children, "odometry", ["odometry", "--prefix", prefix, *files.args("odometry"), *zargs], args.verbose)
        ros2_args = ["ros2", "--flavor", args.ros2, "--prefix", prefix, *files.args("ros2"), *ros2_extra(args), *zargs]
        ros2 = _start(children, "ros2", ros2_args, args.verbose) if args.ros2 else None
        cmd_timeout = float(gateway.wait_ready(READY_TIMEOUT_S).get("cmd_timeout", default_of(GatewaySettings, "cmd_timeout")))
        odometry.wait_ready(READY_TIMEOUT_S)
        ros2_node = ros2.wait_ready(READY_TIMEOUT_S)["node"] if ros2 else None
        view = None
        if args.foxglove:
            view_args = ["foxglove", "--prefix", prefix, "--port", str(args.foxglove_port), *files.args("foxglove"), *zargs]
            view = _start(children, "foxglove", view_args, args.verbose).wait_ready(READY_TIMEOUT_S)["url"]
    except ChildFailed as exc:
        print(f"blackmetal up: {exc}", file=sys.stderr)
        return 1
    print(f"blackmetal is up: {where}, {topology.describe()}, prefix {prefix}", flush=True)
    if ros2_node:
        print(f"ROS 2: node {ros2_node} ({args.ros2}) publishes /odom, /tf, /joint_states and takes /cmd_vel, /estop", flush=True)
    if view:
        print(f"Foxglove: open a Foxglove WebSocket connection to {view} (layout: deploy/foxglove/blackmetal.layout.json)", flush=True)
    print(_drive_help(keys, hub, cmd_timeout), flush=True)
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

    def stop_the_robot() -> str:
        reason = stop_robot(host, control_port, timeout=2.0)
        return "the robot was sent zero velocity and NORMAL_STOP" if reason is None else reason

    return _live(args, children, stop, status.render, {gateway: stop_the_robot})


def _run_fleet(
    args: argparse.Namespace,
    session: zenoh.Session,
    topology: Topology,
    files: ServiceFiles,
    children: list[ServiceProcess],
    stop: threading.Event,
    fleet_file: Path,
) -> int:
    """``--robots N``: one simulator for all, then the fleet gateway and odometry on the file it writes."""
    zargs = topology.child_args()
    hub = topology.endpoint
    poll_args = ["--poll-hz", str(args.poll_hz)] if args.poll_hz is not None else []
    try:
        sim_args = ["sim", "--robots", str(args.robots), "--write-fleet", str(fleet_file), *files.args("sim"), *zargs]
        if args.seed is not None:
            sim_args += ["--seed", str(args.seed)]
        _start(children, "sim", sim_args, args.verbose).wait_ready(READY_TIMEOUT_S)
        robots = load_fleet(fleet_file)  # with the ports the simulator bound
        groups = shards(robots, process_count(len(robots), args.processes))
        gateways: dict[ServiceProcess, list[FleetRobot]] = {}
        odometries: list[ServiceProcess] = []
        for k, group in enumerate(groups, 1):
            suffix = "" if len(groups) == 1 else f"-{k}"
            shard_file = fleet_file if len(groups) == 1 else fleet_file.with_name(f"fleet{suffix}.toml")
            if len(groups) > 1:
                shard_file.write_text(write_fleet(group))
            gateway_args = ["gateway", "--fleet", str(shard_file), *poll_args, *latch_args(args, files), *files.args("gateway"), *zargs]
            gateways[_start(children, f"gateway{suffix}", gateway_args, args.verbose)] = group
            odometry_args = ["odometry", "--fleet", str(shard_file), *files.args("odometry"), *zargs]
            odometries.append(_start(children, f"odometry{suffix}", odometry_args, args.verbose))
        ros2 = None
        if args.ros2:  # one ROS node per robot, /<id>/..., in one adapter process
            ros2_args = ["ros2", "--fleet", str(fleet_file), "--flavor", args.ros2, *files.args("ros2"), *ros2_extra(args), *zargs]
            ros2 = _start(children, "ros2", ros2_args, args.verbose)
        announced = [gateway.wait_ready(READY_TIMEOUT_S) for gateway in gateways]
        cmd_timeout = float(announced[0].get("cmd_timeout", default_of(GatewaySettings, "cmd_timeout")))
        poll_hz = float(announced[0].get("poll_hz", default_of(GatewaySettings, "poll_hz")))
        for odometry in odometries:
            odometry.wait_ready(READY_TIMEOUT_S)
        if ros2 is not None:
            ros2.wait_ready(READY_TIMEOUT_S)
        view = None
        if args.foxglove:  # every robot in one view, /<id>/...
            view_args = ["foxglove", "--fleet", str(fleet_file), "--port", str(args.foxglove_port), *files.args("foxglove"), *zargs]
            view = _start(children, "foxglove", view_args, args.verbose).wait_ready(READY_TIMEOUT_S)["url"]
    except ChildFailed as exc:
        print(f"blackmetal up: {exc}", file=sys.stderr)
        return 1
    shown = robots[0].prefix + (f" ... {robots[-1].prefix}" if len(robots) > 1 else "")
    processes = (
        "one gateway, one odometry process" if len(gateways) == 1 else f"{len(gateways)} gateway and {len(gateways)} odometry processes"
    )
    print(
        f"blackmetal is up: {len(robots)} simulated robots {shown} on {robots[0].host} (one simulator, {processes}), {topology.describe()}",
        flush=True,
    )
    if args.ros2:
        first = robots[0].id
        print(f"ROS 2 ({args.ros2}): one node per robot, /{first}/blackmetal ... with /{first}/cmd_vel, /{first}/odom, "
              f"frames {first}/odom -> {first}/base_footprint on /tf, /{first}/robot_description, services /{first}/set_estop, /{first}/reset_odometry", flush=True)  # fmt: skip
    if view:
        print(f"Foxglove: every robot in one view at {view}, topics /r1/... and /fleet/summary "
              "(layout for r1-r3: deploy/foxglove/blackmetal-fleet.layout.json)", flush=True)  # fmt: skip
    print(_fleet_drive_help(robots, hub, cmd_timeout), flush=True)
    announce_ready(
        "up",
        endpoint=hub,
        prefixes=[r.prefix for r in robots],
        robots=[[r.id, r.prefix, r.host, r.control_port, r.log_port] for r in robots],
        children={child.name: child.proc.pid for child in children},
    )
    status = FleetStatus(session, robots, interval=_status_interval(args), poll_hz=poll_hz)
    stoppers = {gateway: functools.partial(_stop_fleet, group) for gateway, group in gateways.items()}
    return _live(args, children, stop, status.render, stoppers)


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


def _live(
    args: argparse.Namespace,
    children: list[ServiceProcess],
    stop: threading.Event,
    render: Callable[[], str],
    stoppers: Mapping[ServiceProcess, Callable[[], str]],
) -> int:
    """The status line until Ctrl-C (0), or until a child dies (1, reported with its last lines).

    A gateway that dies has its robots stopped first (``stoppers[gateway]``) and is started again, as systemd's
    ``Restart=on-failure`` does, at most :data:`MAX_RESTARTS` times in :data:`RESTART_WINDOW_S`: it comes back with
    the e-stop latch it had. Any other child's death ends up.
    """
    tty = sys.stdout.isatty()
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
            if child in stoppers:  # nobody is left to stop its robots: do it now
                print(f"blackmetal up: {child.name} gone; {stoppers[child]()}", file=sys.stderr, flush=True)
                now = time.monotonic()
                while restarts and restarts[0] < now - RESTART_WINDOW_S:
                    restarts.popleft()
                if len(restarts) < MAX_RESTARTS and not stop.is_set():
                    restarts.append(now)
                    print(
                        f"blackmetal up: {child.name} exited with code {child.proc.returncode}; starting it again "
                        f"({len(restarts)} of at most {MAX_RESTARTS} restarts in {RESTART_WINDOW_S:g} s); its last lines:\n{child.tail()}",
                        file=sys.stderr,
                        flush=True,
                    )
                    child.stop(timeout=1.0)  # reaped, its pipes closed
                    again = ServiceProcess(child.name, child.args, echo=child.echo, own_session=True)
                    children[children.index(child)] = again
                    stoppers[again] = stoppers.pop(child)
                    print(f"blackmetal up: {child.name} started again (pid {again.proc.pid})", file=sys.stderr, flush=True)
                    continue
            print(
                f"blackmetal up: {child.name} exited with code {child.proc.returncode}; its last lines:\n{child.tail()}",
                file=sys.stderr,
                flush=True,
            )
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
