"""up's topology and the fleet's spread over processes: pure decisions from the options."""

from __future__ import annotations

import argparse

import pytest

from blackmetal.runtime.fleet import numbered_fleet
from blackmetal.runtime.zenoh_setup import add_zenoh_arguments
from blackmetal.schemas import ConfigError
from blackmetal.tools.up.topology import Topology, check_fleet_options, process_count, shards


def test_the_fleet_is_spread_over_processes_one_per_150_robots_at_most_one_per_core() -> None:

    assert [process_count(n, None, cores=2) for n in (1, 100, 150, 151, 300, 1000)] == [1, 1, 1, 2, 2, 2]
    assert process_count(1000, None, cores=8) == 7 and process_count(10, 3, cores=1) == 3  # asked: as asked
    groups = shards(numbered_fleet(7), 3)
    assert [[r.id for r in g] for g in groups] == [["r1", "r2", "r3"], ["r4", "r5"], ["r6", "r7"]]


def _topology(*argv: str) -> Topology:
    parser = argparse.ArgumentParser()
    add_zenoh_arguments(parser)
    return Topology(parser.parse_args(list(argv)))


def test_up_is_the_hub_unless_given_only_routers() -> None:
    hub = _topology()
    assert hub.hub and hub.endpoint == "tcp/127.0.0.1:7447" and hub.child_args() == ["-m", "client", "-e", "tcp/127.0.0.1:7447"]
    wide = _topology("-l", "tcp/0.0.0.0:7500")
    assert wide.endpoint == "tcp/127.0.0.1:7500" and wide.describe() == "Zenoh on tcp/127.0.0.1:7500"
    client = _topology("-e", "tcp/10.0.0.1:7447", "-c", "z.json5")
    assert not client.hub and client.child_args() == ["-m", "client", "-e", "tcp/10.0.0.1:7447", "-c", "z.json5"]
    assert client.describe() == "Zenoh via the router at tcp/10.0.0.1:7447 (every process its client)"
    router = _topology("-l", "tcp/[::]:7501", "-e", "tcp/10.0.0.1:7447")
    assert (
        router.settings.mode == "router" and router.describe() == "Zenoh on tcp/127.0.0.1:7501 (a router, connected to tcp/10.0.0.1:7447)"
    )


def test_a_fleet_refuses_a_real_robot() -> None:
    args = argparse.Namespace(robots=3, robot="10.0.0.2", prefix=None, processes=None)
    with pytest.raises(ConfigError, match="--robot HOST drives one real robot"):
        check_fleet_options(args)
