"""``blackmetal ros2`` / ``python -m blackmetal.ros2``: the robot as a ROS 2 node.

/cmd_vel, /estop in; /odom, /tf, /joint_states, /diagnostics out; services
set_estop (std_srvs/SetBool) and reset_odometry (std_srvs/Trigger),
answered once the gateway or the odometry confirms. Nav2's action
navigate_to_pose, /goal_pose and /initialpose go to the navigation
service (<prefix>/nav/...); /tf carries its map -> odom. ``--rmf``: the
same for Open-RMF's free_fleet on plain keys under the robot's name
(<name>/tf, <name>/navigate_to_pose/_action/..., <name>/battery_state).

With ROS 2's Zenoh middleware (``--flavor rmw_zenoh``, the default) connect
to its router: ``blackmetal ros2 -m client -e tcp/localhost:7447``. With
zenoh-bridge-ros2dds (``--flavor bridge``) connect to the bridge.
``--fleet FILE``: one node per robot of a fleet file, each under the
namespace of its id (/r3/cmd_vel, /r3/odom, frames r3/odom, r3/base_footprint).
``--distro humble,jazzy``: one node per distro (rmw_zenoh), each in its
distro's formats, on the one session, for a lab between two distros.
The robot model: /robot_description and /tf_static, transient local, and
the wheels' transforms on /tf (``--no-robot-model`` when
robot_state_publisher publishes them).
"""

from __future__ import annotations

import asyncio
import itertools

from blackmetal.runtime.entry import ServiceCommand, say
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.zenoh_setup import open_service_session
from blackmetal.schemas import Keys

from .action_types import nav_services, nav_topics
from .fleet import FLEET, declare_node
from .host import Ros2Host
from .messages import RosCodec
from .naming import DEFAULT_DISTRO, Direction, Flavor, full_topic, normalise_namespace, services, topics
from .settings import Ros2Settings
from .zenoh_edge import Ros2Zenoh


async def serve(settings: Ros2Settings, stop: asyncio.Event) -> None:
    """Open the Zenoh session, run the adapter (one node per distro) until ``stop``, close everything."""
    codec = RosCodec()  # before Zenoh: a missing extra is one sentence, not a half-open session
    keys = Keys(settings.prefix)
    flavor = Flavor(settings.flavor)
    namespace = normalise_namespace(settings.namespace)
    ros_topics = [*topics(settings.tf, robot_model=settings.robot_model), *nav_topics()]
    ros_services = [*services(), *nav_services()]
    # zenoh-bridge-ros2dds maps DDS, whatever the distro: one node on its plain keys
    distros = settings.distros() if flavor is Flavor.RMW_ZENOH else (DEFAULT_DISTRO,)
    with await open_service_session(settings.zenoh, stop, "ros2") as session:
        ids = itertools.count()  # one counter for the session's nodes and entities, as rmw_zenoh's context keeps
        taken: dict[str, object] = {}  # the action's keys two distros share (Jazzy's and Kilted's): one node serves each
        nodes: list[tuple[str, Ros2Zenoh, Ros2Host]] = []
        try:
            for distro in distros:
                nodes.append((distro.value, *declare_node(session, settings, codec, ids, distro, taken=taken)))
            node = full_topic(namespace, settings.node_name)
            which = ", ".join(d for d, _, _ in nodes) if flavor is Flavor.RMW_ZENOH else "any distro"
            say(f"blackmetal ros2 ready: node {node} ({flavor.value}, {which}, domain {settings.domain_id}) <-> prefix {keys.prefix}")
            names = [*(t.full_name(namespace) for t in ros_topics), *(s.full_name(namespace, settings.node_name) for s in ros_services)]
            width = max(len(n) for n in names)
            for distro_name, edge, _ in nodes:
                say(f"  {distro_name}:" if len(nodes) > 1 else None)
                for topic in ros_topics:
                    way = "ROS -> robot" if topic.direction is Direction.SUBSCRIBE else "robot -> ROS"
                    say(f"  {topic.full_name(namespace):<{width}} {topic.ros_type:<41} {way}  on {edge.data_keys[topic.key_name]}")
                for service in ros_services:
                    name, key = service.full_name(namespace, settings.node_name), edge.service_keys[service.name]
                    say(f"  {name:<{width}} {service.ros_type:<41} service       on {key}")
            say(f"  /cmd_vel drives as the command source {settings.source!r}: {keys.cmd_vel_of(settings.source)}")
            say(f"  navigate_to_pose, /goal_pose, /initialpose <-> {keys.nav_goal}, nav/cancel, nav/result, nav/feedback, nav/set_pose")
            rmf = {
                name: key
                for _, edge, _ in nodes
                for name, key in [*edge.rmf_keys.items(), *edge.data_keys.items()]
                if name.startswith("rmf/")
            }
            if rmf:
                say(f"  Open-RMF free_fleet (plain keys): {', '.join(sorted(rmf.values()))}")
            by_distro = {d: {"keys": e.data_keys, "services": e.service_keys, "tokens": e.tokens} for d, e, _ in nodes}
            first = by_distro[nodes[0][0]]  # the first distro's at the top
            ready = {"prefix": keys.prefix, "node": node, "flavor": flavor.value, "distros": list(by_distro), **first, "rmf": rmf}
            announce_ready("ros2", **ready, by_distro=by_distro)
            await asyncio.gather(*(host.run(stop) for _, _, host in nodes))
        finally:
            for _, edge, _ in nodes:
                edge.close()


COMMAND = ServiceCommand("ros2", Ros2Settings, __doc__, serve, FLEET)
build_parser, run, main = COMMAND.build_parser, COMMAND.run, COMMAND.main
