"""How the view's parts meet, for one robot and for a fleet alike: :class:`Wiring`, keyed by robot id."""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass, field

from blackmetal.runtime.reports import ErrorReporter

from .controls import Controls
from .fleet_view import FLEET_TOPICS, FleetView
from .host import FoxgloveHost
from .live import LiveView
from .naming import FLEET_NAMESPACE
from .watch import Watch
from .zenoh_edge import DRAIN_PERIOD_S, NO_EDGE, FoxgloveZenoh, NoEdge, Reply

log = logging.getLogger("blackmetal.foxglove")


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
        self._descriptions = {view.description_topic: view for view in self.views.values()}

    def plug(self, robot_id: str, edge: FoxgloveZenoh | NoEdge) -> None:
        self.edges[robot_id] = self.controls[robot_id].robot = edge

    def on_health(self, robot_id: str, payload: bytes) -> None:
        self.controls[robot_id].on_health(payload, self.host.clock())
        self.host.poke()

    def on_reset_reply(self, robot_id: str, reply: Reply) -> None:
        self.controls[robot_id].on_reset_reply(*reply, self.host.clock())
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
        elif not following and self._drain is not None:
            self._drain.cancel()
            self._drain = None
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
