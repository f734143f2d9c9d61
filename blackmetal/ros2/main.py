"""``blackmetal ros2`` / ``python -m blackmetal.ros2``: the robot as a ROS 2 node.

/cmd_vel, /estop in; /odom, /tf, /joint_states, /diagnostics out; services
set_estop (std_srvs/SetBool) and reset_odometry (std_srvs/Trigger),
answered once the gateway or the odometry confirms.

With ROS 2's Zenoh middleware (``--flavor rmw_zenoh``, the default) connect
to its router: ``blackmetal ros2 -m client -e tcp/localhost:7447``. With
zenoh-bridge-ros2dds (``--flavor bridge``) connect to the bridge.
``--fleet FILE``: one node per robot of a fleet file, each under the
namespace of its id (/r3/cmd_vel, /r3/odom, frames r3/odom, r3/base_link).
"""

from __future__ import annotations

import argparse
import asyncio

from blackmetal.runtime.entry import run_single_or_fleet, service_parser
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.zenoh_setup import open_service_session
from blackmetal.schemas import Keys

from .core import Ros2Core
from .fleet import SINGLE_ROBOT_OPTIONS, fleet_settings, serve_fleet
from .host import Ros2Host
from .messages import RosCodec
from .naming import Direction, Flavor, full_topic, normalise_namespace, services, topics
from .settings import Ros2Settings
from .zenoh_edge import Ros2Zenoh


async def serve(settings: Ros2Settings, stop: asyncio.Event) -> None:
    """Open the Zenoh session, run the adapter until ``stop``, close everything."""
    codec = RosCodec()  # before Zenoh: a missing extra is one sentence, not a half-open session
    keys = Keys(settings.prefix)
    flavor = Flavor(settings.flavor)
    namespace = normalise_namespace(settings.namespace)
    ros_topics = topics(settings.tf)
    ros_services = services()
    with await open_service_session(settings.zenoh, stop, "ros2") as session:
        edge = Ros2Zenoh(
            session, keys, codec, flavor, settings.domain_id, namespace, settings.node_name, ros_topics, ros_services, settings.source
        )
        host = Ros2Host(Ros2Core(settings.options(edge.data_keys, edge.service_keys), keys, edge, codec))
        edge.attach(host, asyncio.get_running_loop())
        node = full_topic(namespace, settings.node_name)
        print(f"blackmetal ros2 ready: node {node} ({flavor.value}, domain {settings.domain_id}) <-> prefix {keys.prefix}", flush=True)
        for topic in ros_topics:
            way = "ROS -> robot" if topic.direction is Direction.SUBSCRIBE else "robot -> ROS"
            print(f"  {topic.full_name(namespace):<20} {topic.ros_type:<35} {way}  on {edge.data_keys[topic.name]}", flush=True)
        for service in ros_services:
            name, key = full_topic(namespace, service.name), edge.service_keys[service.name]
            print(f"  {name:<20} {service.ros_type:<35} service       on {key}", flush=True)
        print(f"  /cmd_vel drives as the command source {settings.source!r}: {keys.cmd_vel_of(settings.source)}", flush=True)
        announce_ready(
            "ros2",
            prefix=keys.prefix,
            node=node,
            flavor=flavor.value,
            keys=edge.data_keys,
            services=edge.service_keys,
            tokens=edge.tokens,
        )
        try:
            await host.run(stop)
        finally:
            edge.close()


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = service_parser("blackmetal ros2", __doc__, Ros2Settings, parser)
    parser.add_argument(
        "--fleet",
        metavar="FILE",
        help="one ROS node per robot of this fleet file (TOML [[robot]] tables), each under the namespace of its id and "
        "on its prefix, in this one process on one Zenoh session; not with --namespace, --prefix, --node-name",
    )
    return parser


def run(args: argparse.Namespace) -> int:
    return run_single_or_fleet("ros2", args, Ros2Settings, serve, fleet_settings, serve_fleet, SINGLE_ROBOT_OPTIONS)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
