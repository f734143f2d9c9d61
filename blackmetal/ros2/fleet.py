"""``blackmetal ros2 --fleet FILE``: one ROS node per robot of the fleet file, one process, one Zenoh session.

Each robot's node is the single-robot adapter under the ROS namespace of
its id (``/r3/cmd_vel``, ``/r3/odom``, ``/r3/joint_states``, services
``/r3/set_estop`` and ``/r3/reset_odometry``; the node ``/r3/blackmetal``),
reading and writing that robot's prefix (``fleet/r3/...``). Like
diff_drive_controller in a namespace, its frames carry the namespace as a
prefix (``r3/odom``, ``r3/base_footprint``: ``tf_frame_prefix`` left empty) and
its transforms go to the absolute ``/tf`` (``DEFAULT_TRANSFORM_TOPIC``),
one tree for the fleet; its robot model is ``/r3/robot_description`` with
``r3/`` links, its fixed joints on the absolute ``/tf_static``; ``/diagnostics`` stays absolute, each status named
after its node (``r3/blackmetal: robot link``). With rmw_zenoh every node
holds its own tokens, its ids drawn from one counter for the session as
rmw_zenoh numbers a context's nodes and entities; with several distros
(``--distro humble,jazzy``) each robot has one node per distro.

What the nodes share is the process, the loop, the codec and the session.
A robot's bad input is its own (reported on its ``<prefix>/errors``); a bug
in handling one robot fails only its host, which is reported on that
robot's errors key and started again (as ``gateway --fleet`` does).
"""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass

from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.fleet import FleetRobot, supervise
from blackmetal.schemas import ConfigError, ErrorReport, Keys

from .core import Ros2Core
from .host import Ros2Host
from .messages import RosCodec
from .naming import DEFAULT_DISTRO, Distro, Flavor, full_topic, normalise_namespace, services, tf_frame_prefix, topics
from .settings import Ros2Settings
from .zenoh_edge import Ros2Zenoh

#: How often the fleet's loop takes every node's waiting robot samples (s): an /odom is at most this much later than a
#: callback would have made it, and the loop wakes 200 times a second for the whole fleet.
DRAIN_PERIOD_S = 0.005
IDLE_DRAIN_PERIOD_S = 0.1

log = logging.getLogger("blackmetal.ros2")

#: Options for one robot's node: with --fleet each robot's entry decides them.
SINGLE_ROBOT_OPTIONS = {
    "namespace": "each node's namespace is its robot's id (or namespace in its [robot.ros2] table)",
    "prefix": "each node reads and writes its robot's prefix from the fleet file",
    "node_name": "set node_name in a robot's [robot.ros2] table instead",
}


def fleet_settings(base: Ros2Settings, robots: list[FleetRobot]) -> list[Ros2Settings]:
    """Each robot's adapter settings: the command line's, its prefix, the namespace of its id, its [robot.ros2] table."""
    out: list[Ros2Settings] = []
    nodes: dict[tuple[int, str], FleetRobot] = {}
    for robot in robots:
        table = robot.tables.get("ros2", {})
        if "prefix" in table:
            raise ConfigError(f"{robot.describe()}: prefix is not a [robot.ros2] setting; the node uses the robot's own prefix key")
        if "namespace" not in table:
            try:
                normalise_namespace(robot.id)
            except ConfigError:
                raise ConfigError(
                    f"{robot.describe()}: id {robot.id!r} is not a valid ROS namespace (letters, digits and '_', "
                    'not starting with a digit); give the robot one with namespace = "..." in [robot.ros2]'
                ) from None
        settings = robot.settings("ros2", base, {"prefix": robot.prefix, "namespace": robot.id})
        node = full_topic(normalise_namespace(settings.namespace), settings.node_name)
        other = nodes.get((settings.domain_id, node))
        if other is not None:
            raise ConfigError(f"{robot.describe()}: node {node} (domain {settings.domain_id}) is already {other.describe()}'s")
        nodes[(settings.domain_id, node)] = robot
        out.append(settings)
    return out


@dataclass
class Member:
    """One robot's node: its settings, and the host that serves it now (a :class:`~blackmetal.runtime.fleet.Served`)."""

    robot: FleetRobot
    settings: Ros2Settings
    session: object
    codec: RosCodec
    ids: Iterator[int]
    distro: Distro = DEFAULT_DISTRO
    #: The fleet's volatile ROS samples, put back to back at the end of each turn of the loop (one for every node).
    burst: PutBurst | None = None
    host: Ros2Host | None = None
    edge: Ros2Zenoh | None = None
    restarts: int = 0

    def declare(self) -> Ros2Zenoh:
        """Declare this robot's node (new entity ids on each start, as a node created again has), its host, and attach them."""
        s = self.settings
        namespace = normalise_namespace(s.namespace)
        edge = Ros2Zenoh(
            self.session,  # type: ignore[arg-type]
            Keys(s.prefix),
            self.codec,
            Flavor(s.flavor),
            s.domain_id,
            namespace,
            s.node_name,
            topics(s.tf, absolute_tf=True, robot_model=s.robot_model),
            services(),
            s.source,
            self.ids,
            self.distro,
            rings=True,
            burst=self.burst,
        )
        options = s.options(edge.data_keys, edge.service_keys, frame_prefix=tf_frame_prefix(namespace), distro=self.distro)
        self.host = Ros2Host(Ros2Core(options, edge.keys, edge, self.codec), supervised=True)
        self.edge = edge
        edge.attach(self.host, asyncio.get_running_loop())
        return edge

    def start(self) -> Member:
        """The node declared before the fleet was announced serves first; after a failure, a new one."""
        if self.edge is None or self.host is None:
            self.declare()
        return self

    async def run(self, stop: asyncio.Event) -> None:
        assert self.host is not None
        await self.host.run(stop)

    def failed(self, exc: Exception, pause: float) -> None:
        assert self.edge is not None
        self.restarts += 1
        reason = f"ROS 2 node of {self.robot.describe()} failed ({exc!r}, its {self.distro.value} node); starting it again in {pause:g} s"
        log.error("%s", reason)
        self.edge.error(ErrorReport(stamp=time.time(), source="ros2", key=self.edge.keys.errors, reason=reason))

    def close(self) -> None:
        if self.edge is not None:
            self.edge.close()
        self.edge = self.host = None


async def serve_fleet(base: Ros2Settings, robots: list[FleetRobot], stop: asyncio.Event) -> None:
    """Open one Zenoh session and serve one ROS node per robot of the fleet on it until ``stop``."""
    from blackmetal.runtime.harness import announce_ready
    from blackmetal.runtime.zenoh_setup import open_service_session

    codec = RosCodec()  # before Zenoh: a missing extra is one sentence, not a half-open session
    settings = fleet_settings(base, robots)
    ids = itertools.count()  # one counter for the session's nodes and entities, as rmw_zenoh's context keeps
    burst = PutBurst()
    with await open_service_session(base.zenoh, stop, "ros2") as session:
        members = [
            Member(robot, s, session, codec, ids, distro, burst)
            for robot, s in zip(robots, settings, strict=True)
            for distro in (s.distros() if s.flavor == Flavor.RMW_ZENOH.value else (DEFAULT_DISTRO,))
        ]
        for member in members:  # every node declared and serving before the fleet is announced
            member.declare()
        print(f"blackmetal ros2 ready: a fleet of {len(members)} nodes ({base.flavor})", flush=True)
        nodes: dict[str, dict[str, object]] = {}
        for m in members:
            assert m.edge is not None and m.host is not None
            node = full_topic(normalise_namespace(m.settings.namespace), m.settings.node_name)
            frames = m.host.core.options.frames
            print(
                f"  {node:<24} {m.distro.value:<8} domain {m.settings.domain_id} <-> prefix {m.settings.prefix}, "
                f"frames {frames.odom} -> {frames.base}",
                flush=True,
            )
            entry = {
                "node": node,
                "prefix": m.settings.prefix,
                "keys": dict(m.edge.data_keys),
                "services": dict(m.edge.service_keys),
                "tokens": list(m.edge.tokens),
                "frames": dataclasses.asdict(frames),
            }
            robot_entry = nodes.setdefault(m.robot.id, {**entry, "by_distro": {}})  # the first distro's at the top
            robot_entry["by_distro"][m.distro.value] = entry  # type: ignore[index]
        announce_ready("ros2", prefix=robots[0].prefix, prefixes=[r.prefix for r in robots], flavor=base.flavor, nodes=nodes)
        tasks = [asyncio.create_task(supervise(m.start, stop), name=f"ros2 {m.robot.id}") for m in members]
        tasks.append(asyncio.create_task(_drain(members, stop), name="ros2 drain"))
        try:
            await asyncio.gather(*tasks)
        finally:
            burst.flush()  # what the last turn held (cancelled); refused if its node's edge already closed (a normal stop)
            for m in members:
                if m.edge is not None:
                    m.edge.close()


async def _drain(members: list[Member], stop: asyncio.Event) -> None:
    """Every DRAIN_PERIOD_S until ``stop``: each node's followed robot samples to its core (see Ros2Zenoh.drain).

    While no node follows anything (nobody watches), it looks only every IDLE_DRAIN_PERIOD_S: an idle view costs
    nothing; the first samples after someone subscribes wait at most that long in their ring.
    """
    while not stop.is_set():
        active = False
        for member in members:
            edge, host = member.edge, member.host
            if edge is None or host is None or not edge.following():
                continue
            active = True
            try:
                edge.drain()
            except Exception as exc:  # a bug in this node's handling: it alone is started again
                host.fail(exc)
        await asyncio.sleep(DRAIN_PERIOD_S if active else IDLE_DRAIN_PERIOD_S)
