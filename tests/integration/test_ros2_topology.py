"""The README's ROS 2 recipes against ROS 2's real Zenoh graph, emulated.

A ROS 2 system under rmw_zenoh runs ``rmw_zenohd`` (a router with rmw_zenoh's
router config: gossip on, and it does not forward between two peers) and
every node as a *peer* with rmw_zenoh's session config (it connects to the
router, learns the other nodes by gossip and talks to them directly).
Here the router is ``blackmetal router -c deploy/ros2/rmw_zenohd.json5`` on a
free loopback port, and the ROS node is a probe session opened with
``deploy/ros2/ros_node_session.json5``; both files carry rmw_zenoh's settings.
Our processes run as the README starts them. The probe must see the node's
liveliness tokens, receive ``/odom`` and drive the robot with a Twist on
rmw_zenoh's ``/cmd_vel`` key.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh
from helpers import Child, SimProcess, free_port, wait_for
from unit.ros2.test_core import ODOM_KEY, TWIST_KEY, drives, read_odometry

from blackmetal.ros2.messages import RosCodec

pytestmark = pytest.mark.integration

ROS2_DEPLOY = Path(__file__).resolve().parents[2] / "deploy" / "ros2"
ROUTER_CONFIG = ROS2_DEPLOY / "rmw_zenohd.json5"
SESSION_CONFIG = ROS2_DEPLOY / "ros_node_session.json5"


def rmw_zenohd(children: list[Child]) -> str:
    """The ROS 2 router, with rmw_zenoh's router settings, on a free loopback port; its endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = Child(["-m", "blackmetal", "router", "-c", str(ROUTER_CONFIG), "-l", endpoint])
    children.append(router)
    router.ready()
    return endpoint


@pytest.fixture
def ros_node() -> Iterator[object]:
    """Opens probes as rmw_zenoh opens a node's session: a peer, gossip to the router, listening on loopback."""
    opened: list[zenoh.Session] = []

    def open_node(router: str) -> zenoh.Session:
        conf = zenoh.Config.from_file(str(SESSION_CONFIG))
        conf.insert_json5("connect/endpoints", json.dumps([router]))
        conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
        session = zenoh.open(conf)
        opened.append(session)
        return session

    yield open_node
    for session in opened:
        session.close()


def assert_the_ros_graph_meets_the_robot(probe: zenoh.Session) -> None:
    """Tokens of the node and its five topics, /odom samples, and a /cmd_vel Twist that moves the robot."""

    def tokens() -> set[tuple[str, ...]]:
        found = [str(r.ok.key_expr).split("/") for r in probe.liveliness().get("@ros2_lv/0/**", timeout=3) if r.ok is not None]
        seen = {(parts[5], *parts[8:10]) for parts in found}  # kind, node name, topic
        wanted = {("NN", "blackmetal"), ("MP", "blackmetal", "%odom"), ("MP", "blackmetal", "%tf"), ("MS", "blackmetal", "%cmd_vel")}
        return seen if wanted <= seen else set()

    wait_for(tokens, what="the node's liveliness tokens (the node, /odom, /tf, /cmd_vel) at the ROS peer")
    odoms: list[bytes] = []
    subscriber = probe.declare_subscriber(ODOM_KEY, lambda s: odoms.append(s.payload.to_bytes()))
    try:
        wait_for(lambda: len(odoms) >= 5, what="/odom samples at the ROS peer")
        odom = read_odometry(odoms[-1])
        assert odom["frame"] == "odom" and odom["child"] == "base_footprint"
        assert drives(probe, TWIST_KEY, RosCodec().encode_twist(0.3, 0.0), with_attachment=True) > 0.15
    finally:
        subscriber.undeclare()


@pytest.mark.parametrize("hub", [False, True], ids=["every-process-a-client-of-the-router", "up-listens-too"])
def test_up_ros2_joins_a_ros_graph_through_its_router(children: list[Child], ros_node, hub: bool) -> None:  # type: ignore[no-untyped-def]
    """``blackmetal up --ros2 -e ROUTER`` (the README's recipe), and with ``-l`` as well (up's hub is then a router of the graph)."""
    router = rmw_zenohd(children)
    listen = ["-l", f"tcp/127.0.0.1:{free_port()}"] if hub else []
    up = Child(["-m", "blackmetal", "up", "--ros2", *listen, "-e", router])
    children.append(up)
    up.ready(timeout=60)
    assert_the_ros_graph_meets_the_robot(ros_node(router))


def test_ros2_beside_services_joins_a_ros_graph_through_its_router(children: list[Child], ros_node) -> None:  # type: ignore[no-untyped-def]
    """``blackmetal ros2 -e ROUTER`` started on its own, beside a simulator, gateway and odometry that are clients of the router."""
    router = rmw_zenohd(children)
    probe = ros_node(router)  # the ROS side may well be there first
    sim = SimProcess("-e", router)
    children.append(sim)
    gateway = Child(["-m", "blackmetal", "gateway", "--control-port", str(sim.control_port), "--log-port", str(sim.log_port), "-e", router])
    odometry = Child(["-m", "blackmetal", "odometry", "-e", router])
    ros2 = Child(["-m", "blackmetal", "ros2", "-e", router])
    children.extend([gateway, odometry, ros2])
    for child in (gateway, odometry, ros2):
        child.ready()
    ros2.wait_line(rf"blackmetal ros2: connected to {router}")
    assert_the_ros_graph_meets_the_robot(probe)
