"""A stand-in for NavCore that follows the brief's interface: it records every call and answers with canned replies,
so the service's edges are tested without the core helper's controller."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from blackmetal.nav.params import NavParams
from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import (
    ErrorReport,
    GatewayParams,
    Keys,
    MapPose,
    NavCancelReply,
    NavFeedback,
    NavGoalReply,
    NavResult,
    Param,
    ParamsSetReply,
    PayloadError,
    Twist,
    Vector3,
)

Output = Callable[[Twist | NavFeedback | MapPose | GatewayParams | ErrorReport], None]


class FakeNavCore:
    """Records ``(method, *args)`` in :attr:`calls`; a pose while "driving" puts out one Twist (as the real core does)."""

    def __init__(
        self,
        params: NavParams,
        keys: Keys,
        output: Output,
        *,
        map_pose: MapPose,
        geofence: tuple[float, float, float, float] | None = None,
        wallclock: Callable[[], float] = time.time,
    ) -> None:
        self.nav_params, self.keys, self.output, self._map_pose, self.geofence = params, keys, output, map_pose, geofence
        self.reporter = ErrorReporter("nav", output, wallclock)  # type: ignore[arg-type]
        self.calls: list[tuple[Any, ...]] = []
        self.driving = False
        self.deadline = math.inf
        self.ticks: list[float] = []
        self.started = False

    def _record(self, *call: Any) -> None:
        self.calls.append(call)

    def named(self, name: str) -> list[tuple[Any, ...]]:
        return [call for call in self.calls if call[0] == name]

    def on_pose(self, payload: bytes, now: float) -> None:
        self._record("pose", payload, now)
        if self.driving:
            self.output(Twist(linear=Vector3(x=0.1)))

    def on_health(self, payload: bytes, now: float) -> None:
        self._record("health", payload, now)

    def on_driver(self, payload: bytes, now: float) -> None:
        self._record("driver", payload, now)

    def on_gateway_params(self, payload: bytes, now: float) -> None:
        self._record("gateway_params", payload, now)

    def on_alive(self, role: str, alive: bool, now: float) -> None:
        self._record("alive", role, alive, now)

    def on_goal(self, payload: bytes | None, now: float) -> NavGoalReply:
        self._record("goal", payload, now)
        if payload == b"bug":
            raise RuntimeError("a bug in the goal's handling")
        return NavGoalReply(accepted=True, goal_id="0" * 32)

    def on_move(self, payload: bytes | None, now: float) -> NavGoalReply:
        self._record("move", payload, now)
        return NavGoalReply(accepted=False, reason="robot e-stopped")

    def on_cancel(self, payload: bytes | None, now: float) -> NavCancelReply:
        self._record("cancel", payload, now)
        return NavCancelReply(canceled=[], reason="no goal runs")

    def on_result(self, payload: bytes | None, now: float) -> NavResult:
        self._record("result", payload, now)
        return NavResult(found=False, reason="no such goal")

    def on_set_pose(self, payload: bytes | None, now: float) -> MapPose:
        self._record("set_pose", payload, now)
        if not payload:
            self.reporter.report(self.keys.nav_set_pose, "set_pose needs x and y", now=now)
            raise PayloadError("SetPose", "set_pose needs x and y", "")
        self._map_pose = MapPose(stamp=1.0, x=1.0, y=2.0, yaw=0.5, map=self._map_pose.map, by="set_pose")
        self.output(self._map_pose)
        return self._map_pose

    def on_params_set(self, payload: bytes | None, now: float) -> ParamsSetReply:
        self._record("params_set", payload, now)
        return ParamsSetReply(results=[], params=self.params())

    def params(self) -> GatewayParams:
        return GatewayParams(stamp=1.0, params=[Param(name="max_speed", type="double", value=self.nav_params.max_speed)])

    def map_pose(self) -> MapPose:
        return self._map_pose

    def tick(self, now: float) -> None:
        self.ticks.append(now)
        if not self.started:  # the initial map pose and parameters, on the first tick (the brief's contract)
            self.started = True
            self.output(self._map_pose)
            self.output(self.params())
        if now >= self.deadline:
            self.deadline = math.inf

    def next_deadline(self) -> float:
        return self.deadline
