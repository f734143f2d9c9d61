"""Where up's processes meet (the Zenoh topology) and how many carry a fleet: pure decisions, testable without a launch."""

from __future__ import annotations

import argparse
import math
import os

from blackmetal.runtime.fleet import FleetRobot
from blackmetal.runtime.zenoh_setup import DEFAULT_ENDPOINT, zenoh_settings
from blackmetal.schemas import ConfigError

#: Robots one gateway (or odometry) process carries at 50 Hz with room to spare: the fleet gateway took 0.66 cores for
#: 100 robots on the reference machine; past this, --robots spreads them over more processes, one per core at most.
ROBOTS_PER_PROCESS = 150


class Topology:
    """Where up's session and its children meet (docs/commands/up.md): a hub of up's own, or the router of ``-e``
    (with ``-e`` only, every process is its client: ``rmw_zenohd`` does not route between peers)."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.settings = zenoh_settings(args)
        self.routers = list(self.settings.connect)
        self.hub = bool(self.settings.listen) or not self.routers
        if self.hub:
            if not self.settings.listen:
                self.settings.listen = [DEFAULT_ENDPOINT]
            if self.routers and self.settings.mode is None:
                self.settings.mode = "router"
            # where a local child connects to reach the listener (0.0.0.0 / [::] become loopback)
            proto, _, address = self.settings.listen[0].partition("/")
            host, _, port = address.rpartition(":")
            self.endpoint = f"{proto}/{'127.0.0.1' if host in ('0.0.0.0', '[::]', '') else host}:{port}"
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


def check_fleet_options(args: argparse.Namespace) -> None:
    """ConfigError for an option that makes no sense with ``--robots N``."""
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
    """Gateway (and odometry) processes for ``robots``: as asked, else one per ROBOTS_PER_PROCESS, one per core at most."""
    if asked is not None:
        return asked
    return max(1, min(cores or os.cpu_count() or 1, math.ceil(robots / ROBOTS_PER_PROCESS)))


def shards(robots: list[FleetRobot], count: int) -> list[list[FleetRobot]]:
    """``robots`` in ``count`` contiguous groups of near-equal size (r1..r50, r51..r100)."""
    size, extra = divmod(len(robots), count)
    bounds = [k * size + min(k, extra) for k in range(count + 1)]  # the first `extra` groups take one more
    return [robots[bounds[k] : bounds[k + 1]] for k in range(count)]
