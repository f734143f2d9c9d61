"""The gateway's parameters through Foxglove's parameters capability (pure, clock-injected); docs/foxglove.md ("Parameters").

The view keeps no parameter of its own: it shows each gateway's table and sets through the gateway's set key,
with an operator's rights. Foxglove's answer to a set carries values only, so a refusal is a status with the reason.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Iterable
from dataclasses import dataclass, field
from typing import Protocol

import msgspec

from blackmetal.schemas import GatewayParams, Keys, Param, ParamsSet, ParamsSetReply, ParamValue, PayloadError, decode, encode

from .naming import StatusLevel, robot_of
from .zenoh_edge import Wired


class Clients(Protocol):
    """The host as :class:`Parameters` and the controls see it: statuses to a client, answers to calls and sets."""

    def status(self, client: int | None, level: StatusLevel, message: str) -> None: ...
    def answer(self, call: int, response: bytes | None, failure: str | None) -> None: ...
    def parameters_answer(self, call: int, values: list[Param]) -> None: ...
    def parameters_changed(self, values: list[Param]) -> None: ...


def param_name(namespace: str, name: str) -> str:
    """The name Foxglove shows: the gateway's for one robot, ``/r2/max_wheel_speed`` for a fleet's ``r2``."""
    return f"{namespace}/{name}" if namespace else name


@dataclass(slots=True)
class SetCall:
    """A setParameters waiting for its robots' gateways: who asked, the names it showed, the robots still to answer."""

    client: int
    names: list[str]
    waiting: set[str]
    deadline: float
    refusals: list[str] = field(default_factory=list)


@dataclass(slots=True)
class _Robot:
    keys: Keys
    namespace: str
    table: dict[str, Param] = field(default_factory=dict)


class Parameters:
    """Every robot's gateway parameters under Foxglove's names; sets go to the robot's gateway, answers come from its reply."""

    def __init__(self, robots: dict[str, tuple[Keys, str]], output: Clients, call_timeout: float = 2.0) -> None:
        """``robots``: id -> (its keys, its namespace: ``""`` for one robot, ``/<id>`` in a fleet). Its ``gateways`` are
        given by the host that serves these parameters (:meth:`~.host.FoxgloveHost.attach`), before any gateway answers."""
        self.robots = {robot_id: _Robot(keys, namespace) for robot_id, (keys, namespace) in robots.items()}
        self.output = output
        self.gateways: Wired
        self.call_timeout = call_timeout
        self._calls: dict[int, SetCall] = {}
        self._fleet = any(robot.namespace for robot in self.robots.values())

    def _owner(self, shown: str) -> tuple[str, str] | None:
        if not self._fleet:
            (only,) = self.robots
            return only, shown
        robot_id = robot_of(shown, self.robots)
        return None if robot_id is None else (robot_id, shown.removeprefix(self.robots[robot_id].namespace + "/"))

    def _shown(self, robot_id: str, param: Param) -> Param:
        return msgspec.structs.replace(param, name=param_name(self.robots[robot_id].namespace, param.name))

    def values(self, names: Collection[str] = ()) -> list[Param]:
        """The parameters now, by their shown names (all of them when ``names`` is empty; unknown names are left out)."""
        shown = [self._shown(robot_id, param) for robot_id, robot in self.robots.items() for param in robot.table.values()]
        wanted = set(names)
        return [param for param in shown if param.name in wanted] if names else shown

    def on_table(self, robot_id: str, payload: bytes, now: float) -> GatewayParams | None:
        """What changed goes to the clients that follow it; the table (None, reported, when it does not decode)."""
        try:
            table = decode(GatewayParams, payload)
        except PayloadError as exc:
            self.gateways.report(robot_id, "parameters", f"the gateway's parameters did not decode: {exc}", exc.excerpt, now)
            return None
        self._take(robot_id, table.params)
        return table

    def _take(self, robot_id: str, params: Iterable[Param]) -> None:
        robot = self.robots[robot_id]
        changed = []
        for param in params:
            if robot.table.get(param.name) != param:
                robot.table[param.name] = param
                changed.append(self._shown(robot_id, param))
        if changed:
            self.output.parameters_changed(changed)

    def on_set(self, call: int, client: int, values: list[tuple[str, object]], now: float) -> None:
        per_robot: dict[str, dict[str, ParamValue]] = {}
        refusals: list[str] = []
        for shown, value in values:
            owner = self._owner(shown)
            if owner is None:
                reason = f"no parameter {shown!r}: parameters are named /<id>/<name> for the robots {', '.join(self.robots)}"
            elif (isinstance(value, float) and not math.isfinite(value)) or not isinstance(value, (bool, int, float, str)):
                reason = f"{shown} = {value!r} refused: a parameter takes a number, a bool or a string"
            else:
                per_robot.setdefault(owner[0], {})[owner[1]] = value
                continue
            refusals.append(reason)
            self.gateways.report(None if owner is None else owner[0], "parameters", f"client {client}: {reason}", "", now)
        names = [shown for shown, _ in values]
        pending = SetCall(client, names, set(per_robot), now + self.call_timeout, refusals)
        self._calls[call] = pending
        for robot_id, robot_values in per_robot.items():
            self.gateways.set_params(robot_id, call, encode(ParamsSet(values=robot_values)))
        self._finish_if_done(call)

    def on_set_reply(self, robot_id: str, call: int, ok: bytes | None, err: bytes | None, now: float) -> None:
        """``None, None``: the query ended unanswered."""
        pending = self._calls.get(call)
        if pending is None or robot_id not in pending.waiting:
            return
        robot = self.robots[robot_id]
        if ok is not None:
            try:
                reply = decode(ParamsSetReply, ok)
            except PayloadError as exc:
                pending.refusals.append(f"{robot_id}: the gateway answered something else than a ParamsSetReply: {exc}")
            else:
                pending.refusals += [
                    f"{param_name(robot.namespace, result.name)} refused by the gateway: {result.reason}"
                    for result in reply.results
                    if not result.successful
                ]
                self._take(robot_id, reply.params.params)
        elif err is not None:
            reason = err.decode("utf-8", errors="replace") or "no reason given"
            pending.refusals.append(f"the gateway on {robot.keys.prefix!r} refused the set: {reason}")
        else:
            pending.refusals.append(
                f"no gateway answered on {robot.keys.params_set}: is blackmetal gateway running on prefix "
                f"{robot.keys.prefix!r}? nothing was set"
            )
        pending.waiting.discard(robot_id)
        self._finish_if_done(call)

    def _finish_if_done(self, call: int) -> None:
        pending = self._calls.get(call)
        if pending is None or pending.waiting:
            return
        del self._calls[call]
        for reason in pending.refusals:
            self.output.status(pending.client, StatusLevel.ERROR, f"blackmetal: {reason}")
        self.output.parameters_answer(call, self.values(pending.names))

    def tick(self, now: float) -> None:
        for call, pending in list(self._calls.items()):
            if now >= pending.deadline:
                robots = ", ".join(sorted(pending.waiting))
                pending.refusals.append(
                    f"the gateway of {robots} did not answer within {self.call_timeout:g} s; the values shown are the last known"
                )
                pending.waiting.clear()
                self._finish_if_done(call)

    def next_deadline(self) -> float:
        return min((pending.deadline for pending in self._calls.values()), default=math.inf)
