"""``blackmetal ros2`` / ``python -m blackmetal.ros2``: the robot as a ROS 2 node (/cmd_vel, /estop in; /odom, /tf, /joint_states out).

With ROS 2's Zenoh middleware (``--flavor rmw_zenoh``, the default) connect
to its router: ``blackmetal ros2 -m client -e tcp/localhost:7447``. With
zenoh-bridge-ros2dds (``--flavor bridge``) connect to the bridge.
"""

from __future__ import annotations

import argparse
import asyncio

from blackmetal.runtime.entry import run_service, service_parser
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.settings import load_settings
from blackmetal.runtime.zenoh_setup import open_session
from schemas import Keys

from .adapter import AdapterOptions, Ros2Adapter
from .messages import Frames, RosCodec
from .naming import Flavor, full_topic, normalise_namespace
from .settings import Ros2Settings, diagonal_matrix
from .zenoh_edge import Ros2Zenoh, topics

#: How often rate-limited error summaries are published (s).
FLUSH_PERIOD_S = 1.0


async def serve(settings: Ros2Settings, stop: asyncio.Event) -> None:
    codec = RosCodec()  # before Zenoh: a missing extra is one sentence, not a half-open session
    keys = Keys(settings.prefix)
    flavor = Flavor(settings.flavor)
    namespace = normalise_namespace(settings.namespace)
    ros_topics = topics(settings.tf, settings.twist_stamped)
    with open_session(settings.zenoh) as session:
        edge = Ros2Zenoh(session, keys, codec, flavor, settings.domain_id, namespace, settings.node_name, ros_topics)
        options = AdapterOptions(
            frames=Frames(settings.odom_frame, settings.base_frame),
            pose_covariance=diagonal_matrix(settings.pose_covariance_diagonal, "pose_covariance_diagonal"),
            twist_covariance=diagonal_matrix(settings.twist_covariance_diagonal, "twist_covariance_diagonal"),
            publish_tf=settings.tf,
            twist_stamped=settings.twist_stamped,
            joint_names=(settings.left_joint, settings.right_joint),
            wheel_radius=settings.wheel_radius,
            encoders=settings.encoders,
            cmd_vel_key=edge.data_keys["cmd_vel"],
            estop_key=edge.data_keys["estop"],
        )
        adapter = Ros2Adapter(options, keys, edge, codec)
        edge.attach(adapter, asyncio.get_running_loop())
        node = full_topic(namespace, settings.node_name)
        print(f"blackmetal ros2 ready: node {node} ({flavor.value}, domain {settings.domain_id}) <-> prefix {keys.prefix}", flush=True)
        for topic in ros_topics:
            way = "ROS -> robot" if topic.direction.value == "MS" else "robot -> ROS"
            print(f"  {full_topic(namespace, topic.name):<20} {topic.ros_type:<28} {way}  on {edge.data_keys[topic.name]}", flush=True)
        announce_ready("ros2", prefix=keys.prefix, node=node, flavor=flavor.value, keys=edge.data_keys, tokens=edge.tokens)
        try:
            while not stop.is_set():
                try:
                    await asyncio.wait_for(stop.wait(), FLUSH_PERIOD_S)
                except TimeoutError:
                    adapter.reporter.flush()
        finally:
            edge.close()


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    return service_parser("blackmetal ros2", __doc__, Ros2Settings, parser)


def run(args: argparse.Namespace) -> int:
    return run_service("ros2", lambda: load_settings(Ros2Settings, args), serve)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
