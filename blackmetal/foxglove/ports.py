"""How the view's parts meet, for one robot and for a fleet alike: each robot's port, and the wiring of them all.

:class:`RobotPort` takes one robot's edge's answers (health, replies, parameters, liveliness) to its controls,
view and parameters; :class:`Wiring` is what the host and the parameters ask of the view as a whole.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass, field

from blackmetal.runtime.reports import ErrorReporter

from .controls import Controls
from .fleet_view import FleetView
from .host import FoxgloveHost
from .live import LiveView
from .naming import FLEET_NAMESPACE
from .watch import Watch
from .zenoh_edge import DRAIN_PERIOD_S, NO_EDGE, FoxgloveZenoh, NoEdge, Reply

log = logging.getLogger("blackmetal.foxglove")


@dataclass
class RobotPort:
    """One robot's side of the view: its view and controls, its Zenoh edge while the session is open, and the edge's answers in."""

    robot_id: str
    host: FoxgloveHost
    view: LiveView
    controls: Controls
    #: The fleet view, told when the robot's gateway comes and goes (None for one robot).
    fleet: FleetView | None = None
    edge: FoxgloveZenoh | NoEdge = NO_EDGE

    def plug(self, edge: FoxgloveZenoh | NoEdge) -> None:
        self.edge = self.controls.robot = edge

    def on_health(self, payload: bytes) -> None:
        self.controls.on_health(payload, self.host.clock())
        self.host.poke()

    def on_reset_reply(self, reply: Reply) -> None:
        self.controls.on_reset_reply(*reply, self.host.clock())
        self.host.poke()

    def on_params(self, payload: bytes) -> None:
        table = self.host.on_params_table(self.robot_id, payload)
        if table is not None:
            self.view.on_params(table)

    def on_params_reply(self, reply: Reply) -> None:
        self.host.on_params_reply(self.robot_id, reply)

    def on_token(self, alive: bool) -> None:
        """The robot's gateway came (ask its parameters: it may have restarted with others) or went."""
        if self.fleet is not None:
            self.fleet.on_token(self.robot_id, alive)
        if alive:
            self.edge.ask_params()
        self.host.poke()

    def on_bug(self, exc: BaseException) -> None:
        """A handler of this robot's payloads raised: reported on its errors key (rate-limited); the view goes on."""
        name = self.robot_id or self.view.keys.prefix
        log.error("view of robot %s: handler failed: %r", name, exc)
        self.controls.reporter.report("foxglove:view", f"showing {name} failed: {exc!r}", now=self.host.clock())
        self.host.poke()


@dataclass
class Wiring:
    """The host's :class:`~.host.Viewer` and the parameters' :class:`~.params.Gateways` over every robot's port."""

    ports: dict[str, RobotPort]
    watch: Watch
    fleet: FleetView | None = None
    #: Where reports that name no robot go (the fleet's log).
    fleet_reporter: ErrorReporter | None = None
    _peeking: bool = field(default=False, init=False)
    _drain: asyncio.TimerHandle | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        self._descriptions = {port.view.description_topic: port for port in self.ports.values()}

    def subscribed(self, topic: str) -> None:
        port = self._descriptions.get(topic)
        if port is not None:
            port.view.describe()

    def watch_changed(self) -> None:
        needed = self.watch.needed()
        for port in self.ports.values():
            port.edge.want({key for key in port.view.handlers() if key in needed})
        following = any(port.edge.declared for port in self.ports.values())
        if following and self._drain is None:
            self._drain = asyncio.get_running_loop().call_later(DRAIN_PERIOD_S, self._take)
        elif not following and self._drain is not None:
            self._drain.cancel()
            self._drain = None
        if self.fleet is not None:
            follows = any(self.watch.watched(topic) for topic in self.fleet.fleet_topics)
            if not follows:
                self.fleet.suspend()
            peek = self.watch.watched(f"{FLEET_NAMESPACE}/summary")
            if peek != self._peeking:
                self._peeking = peek
                for port in self.ports.values():
                    port.edge.peek(peek)
            self.fleet.poses = self.latest_pose

    def _take(self) -> None:
        self._drain = asyncio.get_running_loop().call_later(DRAIN_PERIOD_S, self._take)
        for port in self.ports.values():
            port.edge.drain()
        next(iter(self.ports.values())).host.poke()

    def stop(self) -> None:
        if self._drain is not None:
            self._drain.cancel()
            self._drain = None

    def latest_pose(self, robot_id: str) -> bytes | None:
        port = self.ports.get(robot_id)
        return port.edge.latest_pose() if port is not None else None

    def ask_params(self, robot_id: str) -> None:
        self.ports[robot_id].edge.ask_params()

    def set_params(self, robot_id: str, call: int, payload: bytes) -> None:
        port = self.ports[robot_id]
        if isinstance(port.edge, NoEdge):
            port.on_params_reply((call, None, None))  # no session: nothing can answer
        else:
            port.edge.set_params(call, payload)

    def report(self, robot_id: str | None, topic: str, reason: str, text: str, now: float) -> None:
        """What the view refused of a parameter set: on the robot's errors key, or the fleet's log when it names none."""
        port = self.ports.get(robot_id) if robot_id is not None else None
        if port is None and len(self.ports) == 1:
            port = next(iter(self.ports.values()))
        if port is not None:
            port.controls.reporter.report(f"foxglove:{topic}", reason, text, now=now)
        elif self.fleet_reporter is not None:
            self.fleet_reporter.report(f"foxglove:{topic}", reason, text, now=now)
