"""``blackmetal foxglove --fleet FILE``: every robot of a fleet file in one view, on one WebSocket server, one Zenoh session.

Names and behaviour: docs/foxglove.md ("A fleet in one view"). What the robots share is the process, the loop,
the server and the session; a bug in handling one robot's payload is reported on that robot's errors key.
How the parts meet (:class:`Wiring`) and are served (:func:`serve_views`) is one robot's view's too (:mod:`.main`).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from blackmetal.robot_model import Encoders
from blackmetal.runtime.entry import Fleet, say
from blackmetal.runtime.fleet import FleetRobot
from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import ConfigError, ErrorReport, Keys, require_extra

from .controls import Controls, FleetControls
from .fleet_view import FLEET_TOPICS, LOST_AFTER_S, FleetView
from .front import INNER_HOST, SUBPROTOCOLS
from .host import FoxgloveHost
from .live import LiveView
from .naming import COMMAND_SOURCE, FLEET_NAMESPACE, Service, nav_takes, robot_frame, robot_namespace, service_name, takes
from .params import Parameters
from .settings import FoxgloveSettings
from .watch import Watch
from .zenoh_edge import DRAIN_PERIOD_S, NO_EDGE, FoxgloveZenoh, NoEdge, Reply

log = logging.getLogger("blackmetal.foxglove")

#: Options for one robot's view: with --fleet the fleet file decides them.
SINGLE_ROBOT_OPTIONS = {"prefix": "each robot's channels read its prefix from the fleet file"}
#: Settings of the one server: the same for every robot, so not in a [robot.foxglove] table.
SERVER_SETTINGS = ("prefix", "host", "port", "mcap", "call_timeout")


def fleet_settings(base: FoxgloveSettings, robots: list[FleetRobot]) -> list[FoxgloveSettings]:
    """Each robot's view settings: the command line's, its prefix, its [robot.foxglove] table (path_length only)."""
    out = []
    for robot in robots:
        if robot_namespace(robot.id) == FLEET_NAMESPACE:
            raise ConfigError(
                f"{robot.describe()}: the Foxglove fleet view keeps {FLEET_NAMESPACE}/ for its own topics; give the robot another id"
            )
        table = robot.tables.get("foxglove", {})
        shared = sorted(set(table) & set(SERVER_SETTINGS))
        if shared:
            raise ConfigError(
                f"{robot.describe()}: {shared[0]} is not a [robot.foxglove] setting; the fleet's one view takes it from its options"
            )
        out.append(robot.settings("foxglove", base, {"prefix": robot.prefix}))
    return out


def encoders(robot: FleetRobot) -> Encoders | None:
    """The robot's own impulses per metre (its calibration in the fleet file) for its wheel speeds; None: the defaults."""
    c = robot.calibration
    if "impulses_left" not in c and "impulses_right" not in c:
        return None
    default = Encoders()
    return Encoders(
        impulses_per_meter_left=c.get("impulses_left", default.impulses_per_meter_left),
        impulses_per_meter_right=c.get("impulses_right", default.impulses_per_meter_right),
    )


@dataclass
class Wiring:
    """Every robot's view, controls and Zenoh edge (while the session is open): the edges' answers go to them, and
    the host and the parameters reach them here (as :class:`~.zenoh_edge.Wired`)."""

    host: FoxgloveHost
    views: dict[str, LiveView]
    controls: dict[str, Controls]
    watch: Watch
    #: The fleet view, told when a robot's gateway comes and goes (None for one robot).
    fleet: FleetView | None = None
    #: Where reports that name no robot go (the fleet's log).
    fleet_reporter: ErrorReporter | None = None
    edges: dict[str, FoxgloveZenoh | NoEdge] = field(init=False)
    _peeking: bool = field(default=False, init=False)
    _drain: asyncio.TimerHandle | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        self.edges = dict.fromkeys(self.views, NO_EDGE)
        for robot_id, view in self.views.items():
            self.controls[robot_id].nav.show = view.nav_event  # the navigation service's answers, on the robot's /log
        self._descriptions = {view.description_topic: view for view in self.views.values()}

    def plug(self, robot_id: str, edge: FoxgloveZenoh | NoEdge) -> None:
        self.edges[robot_id] = self.controls[robot_id].robot = edge

    def on_health(self, robot_id: str, payload: bytes) -> None:
        self.controls[robot_id].on_health(payload, self.host.clock())
        self.host.poke()

    def on_reset_reply(self, robot_id: str, reply: Reply) -> None:
        self.controls[robot_id].on_reset_reply(*reply, self.host.clock())
        self.host.poke()

    def on_nav_reply(self, robot_id: str, reply: Reply) -> None:
        self.controls[robot_id].on_nav_reply(*reply, self.host.clock())
        self.host.poke()

    def on_params(self, robot_id: str, payload: bytes) -> None:
        params = self.host.params
        table = params.on_table(robot_id, payload, self.host.clock()) if params is not None else None
        if table is not None:
            self.views[robot_id].on_params(table)

    def on_params_reply(self, robot_id: str, reply: Reply) -> None:
        if self.host.params is not None:
            self.host.params.on_set_reply(robot_id, *reply, self.host.clock())
            self.host.poke()

    def on_token(self, robot_id: str, alive: bool) -> None:
        """The robot's gateway came (ask its parameters: it may have restarted with others) or went."""
        if self.fleet is not None:
            self.fleet.on_token(robot_id, alive)
        if alive:
            self.edges[robot_id].ask_params()
        self.host.poke()

    def on_bug(self, robot_id: str, exc: BaseException) -> None:
        """A handler of this robot's payloads raised: reported on its errors key (rate-limited); the view goes on."""
        name = robot_id or self.views[robot_id].keys.prefix
        log.error("view of robot %s: handler failed: %r", name, exc)
        self.controls[robot_id].reporter.report("foxglove:view", f"showing {name} failed: {exc!r}", now=self.host.clock())
        self.host.poke()

    def subscribed(self, topic: str) -> None:
        view = self._descriptions.get(topic)
        if view is not None:
            view.describe()

    def watch_changed(self) -> None:
        needed = self.watch.needed()
        for robot_id, view in self.views.items():
            self.edges[robot_id].want({key for key in view.handlers() if key in needed})
        following = any(edge.declared for edge in self.edges.values())
        if following and self._drain is None:
            self._drain = asyncio.get_running_loop().call_later(DRAIN_PERIOD_S, self._take)
        elif not following:
            self.stop()
        if self.fleet is not None:
            follows = any(self.watch.watched(topic) for topic in FLEET_TOPICS)
            if not follows:
                self.fleet.summary.suspend()
            peek = self.watch.watched(f"{FLEET_NAMESPACE}/summary")
            if peek != self._peeking:
                self._peeking = peek
                for edge in self.edges.values():
                    edge.peek(peek)
            self.fleet.poses = self.latest_pose

    def _take(self) -> None:
        self._drain = asyncio.get_running_loop().call_later(DRAIN_PERIOD_S, self._take)
        for edge in self.edges.values():
            edge.drain()
        self.host.poke()

    def stop(self) -> None:
        if self._drain is not None:
            self._drain.cancel()
            self._drain = None

    def latest_pose(self, robot_id: str) -> bytes | None:
        edge = self.edges.get(robot_id)
        return edge.latest_pose() if edge is not None else None

    def ask_params(self, robot_id: str) -> None:
        self.edges[robot_id].ask_params()

    def set_params(self, robot_id: str, call: int, payload: bytes) -> None:
        edge = self.edges[robot_id]
        if isinstance(edge, NoEdge):
            self.on_params_reply(robot_id, (call, None, None))  # no session: nothing can answer
        else:
            edge.set_params(call, payload)

    def report(self, robot_id: str | None, topic: str, reason: str, text: str, now: float) -> None:
        """What the view refused of a parameter set: on the robot's errors key, or the fleet's log when it names none."""
        controls = self.controls.get(robot_id) if robot_id is not None else None
        if controls is None and len(self.controls) == 1:
            (controls,) = self.controls.values()
        if controls is not None:
            controls.reporter.report(f"foxglove:{topic}", reason, text, now=now)
        elif self.fleet_reporter is not None:
            self.fleet_reporter.report(f"foxglove:{topic}", reason, text, now=now)


async def serve_views(
    base: FoxgloveSettings, stop: asyncio.Event, host: FoxgloveHost, wiring: Wiring, announce: Callable[[str], dict[str, Any]]
) -> None:
    """What the view of one robot and of a fleet share once the parts are wired: the session, each robot's edge, the
    announcement (``announce(url)`` returns its part of the ready message), serving until ``stop``, undone after."""
    from blackmetal.runtime.harness import announce_ready
    from blackmetal.runtime.zenoh_setup import open_service_session

    with await open_service_session(base.zenoh, stop, "foxglove") as session:
        loop = asyncio.get_running_loop()
        fleet = wiring.fleet
        edges: list[FoxgloveZenoh] = []
        try:
            for robot_id, view in wiring.views.items():
                edge = FoxgloveZenoh(session, view.keys, query_timeout=base.call_timeout)
                edges.append(edge)
                on_token = partial(wiring.on_token, robot_id)
                handlers, presence = (fleet.handlers(robot_id), on_token) if fleet is not None else (view.handlers(), None)
                edge.attach(robot_id, handlers, wiring, loop, presence=presence)
                wiring.plug(robot_id, edge)
            wiring.watch_changed()  # an MCAP file follows every key from the start; clients, as they subscribe
            for view in wiring.views.values():
                view.describe()  # the URDF, into the MCAP file if there is one (a client gets it when it subscribes)
            info = announce(host.url)
            say(
                f"  (foxglove-sdk serves behind it on {INNER_HOST}:{host.server.port}; connect to {host.url})",
                f"  writing the same channels to {base.mcap}" if base.mcap else None,
            )
            announce_ready("foxglove", url=host.url, port=host.port, subprotocols=list(SUBPROTOCOLS), **info)
            await stop.wait()
        finally:
            wiring.stop()
            for robot_id in wiring.views:
                wiring.plug(robot_id, NO_EDGE)
            for edge in reversed(edges):
                edge.close()


async def serve_fleet(base: FoxgloveSettings, robots: list[FleetRobot], stop: asyncio.Event) -> None:
    require_extra("blackmetal foxglove", "foxglove", "foxglove")
    settings = fleet_settings(base, robots)
    keys = {r.id: Keys(s.prefix) for r, s in zip(robots, settings, strict=True)}
    services = {service_name(robot_namespace(r.id), s): s for r in robots for s in Service}
    host = FoxgloveHost(base, services=services)
    try:
        await host.start()  # the port is taken before Zenoh opens
        view = FleetView([(r.id, keys[r.id], encoders(r), s.path_length) for r, s in zip(robots, settings, strict=True)], clock=host.clock)
        controls = {r.id: Controls(keys[r.id], host, call_timeout=base.call_timeout, namespace=robot_namespace(r.id)) for r in robots}

        def fleet_error(message: ErrorReport) -> None:
            log.warning("%s: %s", message.key, message.reason)
            view.on_fleet_error(message)

        core = FleetControls(controls, host, fleet_error)
        params = Parameters({r.id: (keys[r.id], robot_namespace(r.id)) for r in robots}, host, base.call_timeout)
        wiring = Wiring(host, view.views, controls, Watch(view.feeds(), record_all=bool(base.mcap)), view, core.reporter)
        host.attach(core, params, wiring, view)

        def announce(address: str) -> dict[str, Any]:
            frames = {r.id: [robot_frame(r.id, "odom"), robot_frame(r.id, "base_link")] for r in robots}
            say(
                f"blackmetal foxglove: a fleet of {len(robots)} robots on {address}",
                *(f"  {robot_namespace(r.id) + '/':<8} <-> prefix {keys[r.id].prefix}, frames {' -> '.join(frames[r.id])}" for r in robots),
                f"  open in Foxglove: Open connection > Foxglove WebSocket > {address}",
                f"  {FLEET_NAMESPACE}/summary: one row per robot (lost within {LOST_AFTER_S:g} s); transforms of all on /tf",
                "  each robot's URDF on /<id>/robot_description (links <id>/...), its gateway's parameters as /<id>/<name>",
                f"  clients publish {takes('/<id>')} (as the command source {COMMAND_SOURCE!r})",
                f"  goals from the 3D panel: {nav_takes('/<id>')}; the bare /goal_pose goes to the robot its frame names",
                f"  services: {', '.join(service_name('/<id>', s) for s in Service)}; subprotocols {', '.join(SUBPROTOCOLS)}",
            )
            return {
                "prefix": robots[0].prefix,
                "prefixes": [k.prefix for k in keys.values()],
                "services": list(services),
                "robots": {r.id: {"prefix": keys[r.id].prefix, "namespace": robot_namespace(r.id), "frames": frames[r.id]} for r in robots},
            }

        await serve_views(base, stop, host, wiring, announce)
    finally:
        host.close()


FLEET = Fleet(
    "show every robot of this fleet file (TOML [[robot]] tables) in one view on one port, each under /<id>/ "
    "and on its prefix, with /fleet/summary; not with --prefix",
    fleet_settings,
    serve_fleet,
    SINGLE_ROBOT_OPTIONS,
)
