"""Zenoh edge of the ROS 2 adapter: the robot's keys on one side, ROS topics on the other; declarations only.

For ``rmw_zenoh`` every ROS publication carries rmw_zenoh's attachment and
every entity holds its liveliness token, so ``ros2 node list`` and ``ros2
topic list`` show the node; for ``bridge`` the topics are plain keys, as
zenoh-bridge-ros2dds maps them. Inputs are handed over to the host on the
adapter's asyncio loop (:mod:`blackmetal.runtime.edge`); nothing is decoded
on a Zenoh thread.
"""

from __future__ import annotations

import asyncio
import time
from typing import TYPE_CHECKING

from blackmetal.runtime.edge import Handover, ZenohEdge
from schemas import ErrorReport, Keys, encode

from .host import Ros2Host
from .naming import (
    Direction,
    Flavor,
    NodeIdentity,
    Qos,
    RosTopic,
    attachment,
    bridge_data_key,
    full_topic,
    gid_of,
    rmw_zenoh_data_key,
)

if TYPE_CHECKING:
    import zenoh

    from .messages import RosCodec


class _RosPublisher:
    """A Zenoh publisher on a ROS topic; with rmw_zenoh, each sample carries a rising sequence number."""

    def __init__(self, publisher: "zenoh.Publisher", gid: bytes | None) -> None:
        self.publisher = publisher
        self.gid = gid
        self.sequence = 0

    def put(self, cdr: bytes) -> None:
        if self.gid is None:
            self.publisher.put(cdr)
            return
        self.sequence += 1
        self.publisher.put(cdr, attachment=attachment(self.sequence, time.time_ns(), self.gid))


class Ros2Zenoh(ZenohEdge):
    """Declares the node's ROS side and its blackmetal side on one session."""

    def __init__(
        self,
        session: "zenoh.Session",
        keys: Keys,
        codec: "RosCodec",
        flavor: Flavor,
        domain_id: int,
        namespace: str,
        node_name: str,
        ros_topics: list[RosTopic],
    ) -> None:
        import zenoh

        super().__init__(session)
        self.keys = keys
        node = NodeIdentity(domain_id=domain_id, zid=str(session.zid()), name=node_name, namespace=namespace)
        self.data_keys: dict[str, str] = {}
        self.tokens: list[str] = []
        self._publishers: dict[str, _RosPublisher] = {}
        if flavor is Flavor.RMW_ZENOH:
            self.tokens.append(node.node_token())
        for entity_id, topic in enumerate(ros_topics, start=1):
            name = full_topic(namespace, topic.name)
            if flavor is Flavor.RMW_ZENOH:
                type_hash = codec.type_hash(topic.ros_type)
                key = rmw_zenoh_data_key(domain_id, name, topic.ros_type, type_hash)
                token = node.entity_token(entity_id, topic.direction, name, topic.ros_type, type_hash, Qos())
                self.tokens.append(token)
                gid: bytes | None = gid_of(token)
            else:
                key, gid = bridge_data_key(name), None
            self.data_keys[topic.name] = key
            if topic.direction is Direction.PUBLISH:
                publisher = self.session.declare_publisher(
                    key, congestion_control=zenoh.CongestionControl.DROP, reliability=zenoh.Reliability.RELIABLE
                )
                self._entities.append(publisher)
                self._publishers[topic.name] = _RosPublisher(publisher, gid)
        self._cmd_vel = self.publisher(keys.cmd_vel, express=True)
        self._estop = self.publisher(keys.estop)  # blocking congestion control: a stop is never dropped
        self._errors = self.publisher(keys.errors)

    # Ros2Output
    def ros(self, topic: str, cdr: bytes) -> None:
        self._publishers[topic].put(cdr)

    def blackmetal(self, key: str, payload: bytes) -> None:
        (self._estop if key == self.keys.estop else self._cmd_vel).put(payload)

    def error(self, message: ErrorReport) -> None:
        self._errors.put(encode(message))

    def attach(self, host: Ros2Host, loop: asyncio.AbstractEventLoop) -> Handover:
        handover = Handover(loop)
        self.subscriber(self.data_keys["estop"], handover.channel("estop", host.on_estop, capacity=64, priority=10))
        self.subscriber(self.data_keys["cmd_vel"], handover.channel("cmd_vel", host.on_cmd_vel, latest=True, priority=5))
        self.subscriber(self.keys.pose, handover.channel("pose", host.on_pose, capacity=256))
        self.subscriber(self.keys.impulses, handover.channel("impulses", host.on_impulses, capacity=256))
        for token in self.tokens:  # last: the graph sees the node once it can serve
            self.token(token)
        return handover
