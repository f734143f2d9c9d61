"""Zenoh edge of the ROS 2 adapter: the robot's keys on one side, ROS topics and services on the other; declarations only.

``rmw_zenoh``: every publication carries rmw_zenoh's attachment and every entity holds its liveliness token, in the
node's distro's formats (:mod:`.naming`), so ``ros2 node list`` and the like show the node; ``bridge``: plain keys, as
zenoh-bridge-ros2dds maps them. A stream topic nobody subscribes to costs nothing (:meth:`Ros2Zenoh.follow`); the
inputs always stay declared: a command must always find its way. Threads: docs/threads.md; formats: docs/ros2.md.
"""

from __future__ import annotations

import asyncio
import functools
import itertools
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.edge import ZenohEdge
from blackmetal.runtime.intake import Intake
from blackmetal.runtime.zenoh_entities import undeclare
from blackmetal.schemas import Keys, payload_bytes

from .action_types import GOAL_POSE, INITIAL_POSE, action_hashes, layout_of, nav_services, nav_topics
from .core import NAV_STREAM, WATCHED_FEEDBACK, WATCHED_TOPICS
from .host import Ros2Host
from .naming import (
    CMD_VEL_STAMPED,
    DEFAULT_DISTRO,
    Direction,
    Distro,
    Flavor,
    NodeIdentity,
    Qos,
    RosTopic,
    ServiceRole,
    attachment,
    gid_of,
    normalise_namespace,
    rmw_zenoh_data_key,
    services,
    topics,
    type_hash_of,
)
from .navigate import ACTION_SERVICES, FEEDBACK, MAX_ASKING, RMF, RMF_BATTERY, RMF_TF, STATUS
from .settings import Ros2Settings

if TYPE_CHECKING:
    import zenoh
    import zenoh.ext

    from .messages import RosCodec

#: A fleet node's followed robot streams wait in Zenoh rings of this many until its loop drains them (:meth:`Ros2Zenoh.drain`);
#: the health, kept as the newest only, in a ring of one.
RING = 256

#: rmw_zenoh's SAMPLE_MISS_DETECTION_HEARTBEAT_PERIOD (ms) for a reliable transient-local publisher (rmw_publisher_data.cpp).
HEARTBEAT_S = 0.5


def _payloads_to(put: Callable[[bytes], None]) -> Callable[[Any], None]:
    return lambda sample: put(payload_bytes(sample))


@dataclass
class _RosPublisher:
    """A Zenoh publisher on a ROS topic; with rmw_zenoh, each sample carries a rising sequence number.

    ``burst`` (a fleet's volatile topics): put with the other nodes' samples at the end of the loop's turn."""

    #: None: another node of the session publishes on this very key (see ``taken``): nothing is put here.
    publisher: "zenoh.Publisher | zenoh.ext.AdvancedPublisher | None"
    gid: bytes | None
    burst: PutBurst | None = None
    sequence: int = 0

    def put(self, cdr: bytes) -> None:
        if self.publisher is None:
            return
        extra: bytes | None = None
        if self.gid is not None:
            self.sequence += 1
            extra = attachment(self.sequence, time.time_ns(), self.gid)
        if self.burst is not None:
            self.burst.put(self.publisher, cdr, extra)  # type: ignore[arg-type]
        else:
            self.publisher.put(cdr, attachment=extra)


class Ros2Zenoh(ZenohEdge):
    """Declares the node's ROS side and its blackmetal side on one session."""

    def __init__(
        self,
        session: "zenoh.Session",
        settings: Ros2Settings,
        codec: "RosCodec",
        ids: Iterator[int] | None = None,
        distro: Distro = DEFAULT_DISTRO,
        fleet: bool = False,
        burst: PutBurst | None = None,
        rmf: bool = False,
        taken: dict[str, object] | None = None,
    ) -> None:
        """``ids``: the session's one entity counter, as rmw_zenoh numbers a context's entities (shared by the nodes
        of one session). ``fleet``: the absolute /tf, and the robot's streams wait in Zenoh rings for :meth:`drain`.
        ``rmf``: free_fleet's plain keys too (one node of the robot declares them, whatever its distros). ``taken``: the
        session's keys and which node serves each: two distros with one type hash (Jazzy and Kilted; Lyrical and
        Rolling; all but Humble for most types) have one key, which one node serves (two took every goal and command
        twice, answered every call twice); an absolute topic (/diagnostics, a fleet's /tf) is every node's."""
        import zenoh
        import zenoh.ext

        super().__init__(session)
        self.keys = keys = Keys(settings.prefix)
        flavor, domain_id, node_name = Flavor(settings.flavor), settings.domain_id, settings.node_name
        namespace = normalise_namespace(settings.namespace)
        ros_topics = topics(settings.tf, absolute_tf=fleet, robot_model=settings.robot_model)
        ids = itertools.count() if ids is None else ids
        node = NodeIdentity(domain_id=domain_id, zid=str(session.zid()), name=node_name, namespace=namespace, node_id=next(ids))
        self.data_keys: dict[str, str] = {}
        self.service_keys: dict[str, str] = {}
        self.tokens: list[str] = []
        self._publishers: dict[str, _RosPublisher] = {}
        self._burst = burst
        #: free_fleet's services ("rmf/" + the action's service name) -> their plain keys.
        self.rmf_keys: dict[str, str] = {}
        known_hashes = action_hashes(layout_of(distro))  # the action's types, not in the codec's store
        self._taken: dict[str, object] = {} if taken is None else taken
        self._elsewhere: set[str] = set()  # the topics and services another node of the session serves (same key)
        if flavor is Flavor.RMW_ZENOH:
            self.tokens.append(node.node_token())

        def declare(kind: Direction | ServiceRole, name: str, ros_type: str, qos: Qos) -> tuple[str, bytes | None]:
            """The entity's key and, with rmw_zenoh, its GID (its token goes to :attr:`tokens`)."""
            entity_id = next(ids)
            if flavor is not Flavor.RMW_ZENOH:
                return name.strip("/"), None  # zenoh-bridge-ros2dds: the topic name
            type_hash = type_hash_of(distro, known_hashes.get(ros_type) or codec.type_hash(ros_type))
            token = node.entity_token(entity_id, kind, name, ros_type, type_hash, qos)
            self.tokens.append(token)
            return rmw_zenoh_data_key(domain_id, name, ros_type, type_hash), gid_of(token)

        def place(topic: RosTopic) -> None:
            """Declare ``topic`` unless another node of the session has its key (an absolute topic: every node's)."""
            key, gid = declare(topic.direction, topic.full_name(namespace), topic.ros_type, topic.qos)
            self.data_keys[topic.key_name] = key
            if not topic.absolute and not self._own(key):
                self._elsewhere.add(topic.key_name)
                self._publishers[topic.key_name] = _RosPublisher(None, None)
            elif topic.direction is Direction.PUBLISH:
                self._declare_publisher(topic.key_name, key, gid, topic.qos)

        for topic in ros_topics:
            place(topic)
        # the action's entities after the services, so that the entities before them keep their ids
        for service in [*services(), *nav_services()]:
            name = service.full_name(namespace, node_name)
            key = self.service_keys[service.name] = declare(ServiceRole.SERVER, name, service.ros_type, service.qos)[0]
            if not self._own(key):
                self._elsewhere.add(service.name)
        for topic in nav_topics():
            place(topic)
        if rmf:  # zenoh-bridge-ros2dds's plain keys under the robot's RMF name: no type, no hash, no attachment
            robot = settings.rmf_robot()
            battery = (RMF_BATTERY,) if settings.rmf_battery >= 0 else ()  # a robot with no battery gauge: none
            for name in (RMF_TF, RMF + FEEDBACK, RMF + STATUS, *battery):
                key = f"{robot}/{name.removeprefix(RMF)}"
                self.data_keys[name] = key
                self._declare_publisher(name, key, None, Qos())
            self.rmf_keys = {RMF + name: f"{robot}/{name}" for name in ACTION_SERVICES}
        # drop congestion control, as rmw_zenoh put the command: the direct take's Zenoh thread never waits on a link
        self._cmd_vel = self.session.declare_publisher(
            keys.cmd_vel_of(settings.source),
            encoding=zenoh.Encoding.APPLICATION_JSON,
            express=True,
            congestion_control=zenoh.CongestionControl.DROP,
        )
        self._entities.append(self._cmd_vel)
        # blocking congestion control: a stop is never dropped; a release goes to the key a safety role may put on
        self._estop = {key: self.publisher(keys, key) for key in (keys.estop, keys.estop_release)}
        self.routes(keys, [keys.errors])
        self._calls: dict[int, tuple["zenoh.Query", str]] = {}
        self._next_call = 0
        self._streams: dict[str, tuple[str, Callable[[bytes], None], Callable[[bytes], None], int]] = {}
        self._followed: dict[str, Any] = {}
        self._rings = fleet
        self._host: Ros2Host | None = None
        self._put_query_event: Callable[[tuple[int, bool | None, bytes]], None] | None = None

    def _own(self, key: str) -> bool:
        """Serve ``key`` unless another node of the session does (it is this node's from now on)."""
        return self._taken.setdefault(key, self) is self

    def _declare_publisher(self, name: str, key: str, gid: bytes | None, qos: Qos) -> None:
        """A ROS topic's publisher: transient local as rmw_zenoh declares one (an AdvancedPublisher with its cache)."""
        import zenoh
        import zenoh.ext

        drop, reliable = zenoh.CongestionControl.DROP, zenoh.Reliability.RELIABLE
        if qos.is_transient_local:
            publisher: zenoh.Publisher | zenoh.ext.AdvancedPublisher = zenoh.ext.declare_advanced_publisher(
                self.session,
                key,
                congestion_control=drop,
                reliability=reliable,
                cache=zenoh.ext.CacheConfig(max_samples=qos.depth),
                publisher_detection=True,
                sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=HEARTBEAT_S),
            )
        else:
            publisher = self.session.declare_publisher(key, congestion_control=drop, reliability=reliable)
        self._entities.append(publisher)
        self._publishers[name] = _RosPublisher(publisher, gid, None if qos.is_transient_local else self._burst)

    def ros(self, topic: str, cdr: bytes) -> None:
        self._publishers[topic].put(cdr)

    def blackmetal(self, key: str, payload: bytes) -> None:
        """The e-stop or its release (on the loop, never dropped), or the source's command (on the loop or a direct take's Zenoh thread)."""
        self._estop.get(key, self._cmd_vel).put(payload)

    error = ZenohEdge.publish

    def service_reply(self, call: int, cdr: bytes, attachment: bytes | None) -> None:
        entry = self._calls.pop(call, None)
        if entry is not None:
            query, key = entry
            with query:
                query.reply(key, cdr, attachment=attachment)

    def service_refuse(self, call: int, reason: str) -> None:
        entry = self._calls.pop(call, None)
        if entry is not None:
            with entry[0] as query:
                query.reply_err(reason.encode())

    def query(self, key: str, payload: bytes | None, tag: int, timeout: float) -> None:
        import zenoh

        put = self._put_query_event
        assert put is not None, "attach() first"

        def on_reply(reply: "zenoh.Reply") -> None:
            if reply.ok is not None:
                put((tag, True, bytes(reply.ok.payload.to_bytes())))
            elif reply.err is not None:
                put((tag, False, bytes(reply.err.payload.to_bytes())))

        replies = zenoh.handlers.Callback(on_reply, lambda: put((tag, None, b"")))
        self.session.get(key, replies, payload=payload, timeout=timeout)

    def attach(self, host: Ros2Host, loop: asyncio.AbstractEventLoop) -> Intake:
        driver, core = host.driver, host.core
        intake = self.intake(loop, on_error=driver.on_error(), lock=host.lock)
        self._host = host

        def on(method: Callable[..., Any]) -> Callable[[Any], Any]:
            return driver.handler(method, unpack=False)

        # the action's queries of the navigation service are at most MAX_ASKING at once: a reply and a done each
        self._put_query_event = intake.channel("query replies", self._on_query_event, capacity=4 * MAX_ASKING, priority=8)
        if "estop" not in self._elsewhere:
            self.subscriber(self.data_keys["estop"], intake.channel("estop", on(core.on_estop), capacity=64, priority=10))
        twist = intake.channel("cmd_vel", on(core.on_cmd_vel), latest=True, priority=5, direct=host.direct())
        if "cmd_vel" not in self._elsewhere:
            self.subscriber(self.data_keys["cmd_vel"], twist)
        on_stamped = on(functools.partial(core.on_cmd_vel, stamped=True))
        stamped = intake.channel(CMD_VEL_STAMPED, on_stamped, latest=True, priority=5, direct=host.direct(stamped=True))
        if CMD_VEL_STAMPED not in self._elsewhere:
            self.subscriber(self.data_keys[CMD_VEL_STAMPED], stamped)
        # the robot streams it follows (ring drains and callbacks meet the same handler): key, method, channel, ring
        streams: dict[str, tuple[str, Callable[..., Any], dict[str, Any], int]] = {
            "pose": (self.keys.pose, core.on_pose, {"capacity": 256}, RING),
            "impulses": (self.keys.impulses, core.on_impulses, {"capacity": 256}, RING),
            "errors": (self.keys.errors, core.on_error_report, {"capacity": 256}, RING),
            "health": (self.keys.health, core.on_health, {"latest": True, "priority": 8}, 1),
            NAV_STREAM: (self.keys.nav_feedback, core.nav.on_feedback, {"capacity": 256, "priority": 6}, RING),
        }
        self._streams = {
            name: (key, intake.channel(name, on(method), **options), on(method), ring)
            for name, (key, method, options, ring) in streams.items()
        }
        self.subscriber(self.keys.params, intake.channel("params", on(core.calls.on_params), latest=True, priority=8))
        # navigation: RViz's pose tools in, the navigation service's map frame in (its feedback: a stream, above)
        for tool, method in ((GOAL_POSE, core.on_goal_pose), (INITIAL_POSE, core.on_initial_pose)):
            if tool not in self._elsewhere:
                self.subscriber(self.data_keys[tool], intake.channel(tool, on(method), capacity=16, priority=7))
        self.subscriber(self.keys.nav_map_pose, intake.channel("nav map_pose", on(core.nav.on_map_pose), latest=True, priority=6))

        def on_matched(event: tuple[str, bool]) -> None:
            host.driver.run_locked(core.on_matched, *event)

        matched = intake.channel("matching", on_matched, capacity=64, priority=7)
        for topic in (*WATCHED_TOPICS, *WATCHED_FEEDBACK):
            entry = self._publishers.get(topic)
            if entry is not None and entry.publisher is not None:
                self._watch(topic, entry.publisher, matched)
        for who, key in (("gateway", self.keys.alive_gateway), ("odometry", self.keys.alive_odometry), ("nav", self.keys.alive_nav)):
            on_alive = functools.partial(host.driver.run_locked, core.on_alive, who)
            self._alive(key, intake.channel(f"alive {who}", on_alive, capacity=16, priority=9))
        for service, key in [*self.service_keys.items(), *self.rmf_keys.items()]:
            if service in self._elsewhere:
                continue
            # a query dropped from a full channel is never answered: the action's take a flood of goals (free_fleet's
            # dispatchers, scripts) and answer each, refusing what is beyond MAX_ASKING
            capacity = 4 * MAX_ASKING if service.removeprefix(RMF) in ACTION_SERVICES else 16
            take = intake.channel(f"{service}?", functools.partial(self._take_call, service), capacity=capacity, priority=9)
            # complete: rmw_zenoh's client targets ALL_COMPLETE queryables only
            self._entities.append(self.session.declare_queryable(key, take, complete=True))
        for token in self.tokens:  # last: the graph sees the node once it can serve
            self.token(token)
        return intake

    def _watch(self, topic: str, publisher: Any, put: Callable[[tuple[str, bool]], None]) -> None:
        self.watch_matching(publisher, lambda matched: put((topic, matched)))

    def follow(self, streams: frozenset[str]) -> None:
        """Subscribe to exactly these of the robot's streams (``pose``, ``impulses``, ``errors``, ``health``,
        ``nav_feedback``); on the loop."""
        for name in [n for n in self._followed if n not in streams]:
            undeclare(self._followed.pop(name))
        for name in sorted(streams):
            if name not in self._followed and name in self._streams:
                key, put, _, ring = self._streams[name]
                if self._rings:
                    import zenoh

                    self._followed[name] = self.session.declare_subscriber(key, zenoh.handlers.RingChannel(ring))
                else:
                    self._followed[name] = self.session.declare_subscriber(key, _payloads_to(put))

    def following(self) -> bool:
        """Whether a fleet's loop drains this node at its busy pace: a watched stream is followed, or the navigation's
        feedback (always followed, drained here at the idle pace) has just brought samples: an idle fleet stays idle."""
        if any(name != NAV_STREAM for name in self._followed):
            return True
        return self.drain(only=NAV_STREAM) > 0

    def drain(self, only: str | None = None) -> int:
        """On the loop (a fleet node): hand the rings' waiting samples to the host under its lock, oldest first; how many.

        No Python runs per sample on Zenoh's threads. A handler's exception propagates: the fleet fails this node alone.
        ``only``: that stream's ring alone."""
        host = self._host
        if not self._rings or host is None or not host.driver.serving or not self._followed:
            return 0
        taken = 0
        for name, subscriber in list(self._followed.items()):
            if only is not None and name != only:
                continue
            # the first sample is taken before the lock (rings are thread-safe): most drains find every ring empty
            ring = subscriber  # (a name of its own: the identity tests below narrow ``subscriber`` for mypy)
            sample = ring.try_recv() if self._followed.get(name) is subscriber else None
            if sample is None:
                continue
            handler = self._streams[name][2]
            with host.lock:
                while sample is not None:
                    taken += 1
                    handler(payload_bytes(sample))
                    if self._followed.get(name) is not subscriber:  # the handler had the core unfollow it
                        break
                    sample = ring.try_recv()
        return taken

    def _alive(self, key: str, put: Callable[[bool], None]) -> None:
        import zenoh

        def on_sample(sample: "zenoh.Sample") -> None:
            put(sample.kind == zenoh.SampleKind.PUT)

        self._entities.append(self.session.liveliness().declare_subscriber(key, on_sample, history=True))

    def _take_call(self, service: str, query: "zenoh.Query") -> None:
        """On the loop: number the call, keep the query until the core answers it, hand the request to the host."""
        assert self._host is not None
        self._next_call += 1
        self._calls[self._next_call] = (query, self.service_keys.get(service) or self.rmf_keys[service])
        payload = b"" if query.payload is None else bytes(query.payload.to_bytes())
        extra = None if query.attachment is None else bytes(query.attachment.to_bytes())
        self._host.driver.run_locked(self._host.core.on_service_request, service, self._next_call, payload, extra)

    def _on_query_event(self, event: tuple[int, bool | None, bytes]) -> None:
        assert self._host is not None
        tag, ok, payload = event
        if ok is None:
            self._host.driver.run_locked(self._host.core.on_query_done, tag)
        else:
            self._host.driver.run_locked(self._host.core.on_query_reply, tag, ok, payload)

    def close(self) -> None:
        for key in [k for k, owner in self._taken.items() if owner is self]:  # a node started again takes them anew
            del self._taken[key]
        for query, _ in self._calls.values():  # unanswered calls end with the adapter
            query.drop()
        self._calls.clear()
        for subscriber in self._followed.values():
            undeclare(subscriber)
        self._followed.clear()
        super().close()
