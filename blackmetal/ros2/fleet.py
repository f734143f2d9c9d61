"""``blackmetal ros2 --fleet FILE``: one ROS node per robot of the fleet file, one process, one Zenoh session.

Each robot's node is the single-robot adapter under the namespace of its id, its frames prefixed as
diff_drive_controller prefixes them, its transforms on the absolute ``/tf`` (docs/ros2-adapter.md "A fleet").
A bug in handling one robot fails only its node, which is reported on that robot's errors key and started again.
"""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
from collections.abc import Iterator
from typing import Any

from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.entry import Fleet, say
from blackmetal.runtime.fleet import FleetRobot
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.service import Member, Role, serve_fleet
from blackmetal.schemas import ConfigError

from .core import Ros2Core
from .host import Ros2Host
from .messages import RosCodec
from .naming import DEFAULT_DISTRO, Distro, Flavor, full_topic, normalise_namespace, tf_frame_prefix
from .settings import Ros2Settings
from .zenoh_edge import Ros2Zenoh

#: How often the fleet's loop takes every node's waiting robot samples (s): an /odom is at most this much later than a
#: callback would have made it, and the loop wakes 200 times a second for the whole fleet.
DRAIN_PERIOD_S = 0.005
IDLE_DRAIN_PERIOD_S = 0.1

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
    rmf_names: dict[str, FleetRobot] = {}
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
        if settings.rmf:
            other = rmf_names.get(settings.rmf_robot())
            if other is not None:
                raise ConfigError(
                    f"{robot.describe()}: free_fleet's name {settings.rmf_robot()!r} is already {other.describe()}'s: "
                    'give one of them rmf_name = "..." in [robot.ros2]'
                )
            rmf_names[settings.rmf_robot()] = robot
        out.append(settings)
    return out


def declare_node(
    session: Any,
    s: Ros2Settings,
    codec: RosCodec,
    ids: Iterator[int],
    distro: Distro,
    burst: PutBurst | None = None,
    taken: dict[str, object] | None = None,
) -> tuple[Ros2Zenoh, Ros2Host]:
    """One node of ``distro`` for the robot of ``s``, attached to the running loop; with ``burst``, a fleet's node
    (absolute /tf, frames prefixed by its namespace, streams in rings, supervised). ``taken``: the session's action
    keys and who serves each (:class:`Ros2Zenoh`)."""
    fleet = burst is not None
    first = s.distros()[0] if s.flavor == Flavor.RMW_ZENOH.value else DEFAULT_DISTRO
    rmf = s.rmf and distro is first  # free_fleet's keys once per robot, on its first distro's node
    edge = Ros2Zenoh(session, s, codec, ids, distro, fleet=fleet, burst=burst, rmf=rmf, taken=taken)
    frame_prefix = tf_frame_prefix(normalise_namespace(s.namespace)) if fleet else ""
    options = s.options(edge.data_keys, edge.service_keys, frame_prefix=frame_prefix, distro=distro)
    if not rmf:
        options = dataclasses.replace(options, rmf_name="")
    host = Ros2Host(Ros2Core(options, edge.keys, edge, codec), supervised=fleet)
    edge.attach(host, asyncio.get_running_loop())
    return edge, host


async def serve(base: Ros2Settings, robots: list[FleetRobot], stop: asyncio.Event) -> None:
    codec = RosCodec()  # before Zenoh: a missing extra is one sentence, not a half-open session
    ids = itertools.count()  # one counter for the session's nodes and entities, as rmw_zenoh's context keeps
    taken: dict[str, object] = {}  # the session's action keys: one node serves each
    failure = "ROS 2 node of {robot} failed ({exc!r}, its %s node); starting it again in {pause:g} s"

    def role(d: Distro) -> Role[Ros2Settings]:
        return Role("ros2", lambda m: declare_node(m.session, m.settings, codec, ids, d, m.burst, taken), failure % d.value)

    roles = {d: role(d) for d in Distro}
    parts = [
        (roles[distro], robot, s)
        for robot, s in zip(robots, fleet_settings(base, robots), strict=True)
        for distro in (s.distros() if s.flavor == Flavor.RMW_ZENOH.value else (DEFAULT_DISTRO,))
    ]

    def announce(members: list[Member[Ros2Settings]]) -> None:
        say(f"blackmetal ros2 ready: a fleet of {len(members)} nodes ({base.flavor})")
        nodes: dict[str, dict[str, object]] = {}
        for m in members:
            name = full_topic(normalise_namespace(m.settings.namespace), m.settings.node_name)
            frames = m.host.core.options.frames
            distro = next(d.value for d, r in roles.items() if r is m.role)
            say(
                f"  {name:<24} {distro:<8} domain {m.settings.domain_id} <-> prefix {m.settings.prefix}, frames {frames.odom} -> {frames.base}"
            )
            entry = {
                "node": name,
                "prefix": m.settings.prefix,
                "keys": dict(m.edge.data_keys),
                "services": dict(m.edge.service_keys),
                "rmf": {k: v for k, v in [*m.edge.rmf_keys.items(), *m.edge.data_keys.items()] if k.startswith("rmf/")},
                "tokens": list(m.edge.tokens),
                "frames": dataclasses.asdict(frames),
            }
            robot_entry = nodes.setdefault(m.robot.id, {**entry, "by_distro": {}})  # the first distro's at the top
            robot_entry["by_distro"][distro] = entry  # type: ignore[index]
        announce_ready("ros2", prefix=robots[0].prefix, prefixes=[r.prefix for r in robots], flavor=base.flavor, nodes=nodes)

    await serve_fleet(base.zenoh, stop, parts, announce, drain_every=(DRAIN_PERIOD_S, IDLE_DRAIN_PERIOD_S))


FLEET = Fleet(
    "one ROS node per robot of this fleet file (TOML [[robot]] tables), each under the namespace of its id and "
    "on its prefix, in this one process on one Zenoh session; not with --namespace, --prefix, --node-name",
    fleet_settings,
    serve,
    SINGLE_ROBOT_OPTIONS,
)
