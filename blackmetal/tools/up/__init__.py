"""``blackmetal up``: the simulated robot, the gateway, the odometry and the navigation service in one command.

Each runs as its own process; this one holds the Zenoh endpoint that clients
connect to (``tcp/127.0.0.1:7447`` unless ``-l`` says otherwise), prints how
to drive the robot, then a live one-line status. Given a router with ``-e``
and no ``-l`` (ROS 2's ``rmw_zenohd``, a fleet's router), it holds no
endpoint: every process of the demo is a client of that router. Ctrl-C stops
everything within 3 s; a child that dies is reported with its last lines.

With ``--robots N``: a fleet of N simulated robots r1 ... rN under
``fleet/<id>``, in four processes whatever N (``sim --robots N``,
``gateway --fleet``, ``odometry --fleet``, ``nav --fleet``, sharing the
fleet file the simulator writes), and one live status line for the whole fleet.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from blackmetal.foxglove.settings import FoxgloveSettings
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.ros2.naming import Flavor, parse_distros
from blackmetal.ros2.settings import Ros2Settings
from blackmetal.runtime.harness import stop_in_order
from blackmetal.runtime.settings import default_of
from blackmetal.runtime.signals import stop_on_signals
from blackmetal.runtime.zenoh_setup import add_zenoh_arguments, open_when_reachable
from blackmetal.schemas import DEFAULT_PREFIX, ConfigError, Keys, require_extra, validate_prefix

from ..client import tool
from .launch import STOP_BUDGET_S, Launch, run_fleet, run_one
from .settings import ServiceFiles
from .settings import ros2_extra as ros2_extra  # the ROS 2 tests' way in
from .topology import ROBOTS_PER_PROCESS, Topology, check_fleet_options


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    """up's own options; the defaults of those it passes on are the services' settings defaults."""
    control_port, log_port = default_of(GatewaySettings, "control_port"), default_of(GatewaySettings, "log_port")
    parser = parser or argparse.ArgumentParser(prog="blackmetal up", description=__doc__)
    parser.add_argument("--robot", metavar="HOST", help="drive a real robot at HOST instead of the simulator")
    parser.add_argument(
        "--robots",
        type=int,
        metavar="N",
        help="a fleet: N simulated robots r1..rN under fleet/<id>, in one simulator, one gateway, one odometry and one nav "
        "process (--fleet), with one status line for all",
    )
    parser.add_argument(
        "--processes",
        type=int,
        metavar="K",
        help=f"with --robots: spread the robots over K gateway, K odometry and K nav processes (default: one per "
        f"{ROBOTS_PER_PROCESS} robots, at most one per core)",
    )
    parser.add_argument("--control-port", type=int, default=control_port, help=f"robot control port with --robot (default {control_port})")
    parser.add_argument("--log-port", type=int, default=log_port, help=f"robot log port with --robot (default {log_port})")
    parser.add_argument("--prefix", help=f"key-expression prefix (default: the --settings file's prefix, else {DEFAULT_PREFIX})")
    parser.add_argument(
        "--poll-hz",
        type=float,  # not given: the gateway's own default (or the --settings file) applies
        help=f"wheel polls per second (default {default_of(GatewaySettings, 'poll_hz'):g})",
    )
    parser.add_argument("--seed", type=int, help="simulator fault seed")
    parser.add_argument(
        "--settings",
        metavar="FILE",
        help="settings file with any service's keys, each service takes its own (e.g. from blackmetal calibrate); "
        "or sections [gateway], [odometry], [nav], [sim], [ros2], [foxglove]",
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
    services = ["gateway", "odometry", "nav", *([] if args.robot else ["sim"]), *(["ros2"] if args.ros2 else []),
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
        if (session := open_when_reachable(topology.settings, stop, "up")) is None:
            return 0  # Ctrl-C while waiting for the router
        launch = Launch(args, files, topology, [])
        try:
            if fleet:
                with tempfile.TemporaryDirectory(prefix="blackmetal-fleet-") as workdir:
                    return run_fleet(launch, session, stop, Path(workdir) / "fleet.toml")
            return run_one(launch, keys, session, stop)
        finally:
            # nav, odometry and gateway first (the gateway stops the robot), then the simulator
            children = launch.children
            stop_in_order([[c for c in children if c.name != "sim"], [c for c in children if c.name == "sim"]], STOP_BUDGET_S - 0.3)
            session.close()
    finally:
        files.close()
