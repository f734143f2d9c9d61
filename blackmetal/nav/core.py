"""PLACEHOLDER (the core helper's nav/core.py replaces it): NavCore's interface, as the brief gives it."""

from __future__ import annotations

import time
from collections.abc import Callable

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
    ParamsSetReply,
    Twist,
)

from .params import NavParams

NavOutput = Callable[[Twist | NavFeedback | MapPose | GatewayParams | ErrorReport], None]


class NavCore:
    def __init__(
        self,
        params: NavParams,
        keys: Keys,
        output: NavOutput,
        *,
        map_pose: MapPose,
        geofence: tuple[float, float, float, float] | None = None,
        wallclock: Callable[[], float] = time.time,
    ) -> None:
        self.reporter = ErrorReporter("nav", output, wallclock)
        raise NotImplementedError

    def on_pose(self, payload: bytes, now: float) -> None:
        raise NotImplementedError

    def on_health(self, payload: bytes, now: float) -> None:
        raise NotImplementedError

    def on_driver(self, payload: bytes, now: float) -> None:
        raise NotImplementedError

    def on_gateway_params(self, payload: bytes, now: float) -> None:
        raise NotImplementedError

    def on_alive(self, role: str, alive: bool, now: float) -> None:
        raise NotImplementedError

    def on_goal(self, payload: bytes | None, now: float) -> NavGoalReply:
        raise NotImplementedError

    def on_move(self, payload: bytes | None, now: float) -> NavGoalReply:
        raise NotImplementedError

    def on_cancel(self, payload: bytes | None, now: float) -> NavCancelReply:
        raise NotImplementedError

    def on_result(self, payload: bytes | None, now: float) -> NavResult:
        raise NotImplementedError

    def on_set_pose(self, payload: bytes | None, now: float) -> MapPose:
        raise NotImplementedError

    def on_params_set(self, payload: bytes | None, now: float) -> ParamsSetReply:
        raise NotImplementedError

    def params(self) -> GatewayParams:
        raise NotImplementedError

    def map_pose(self) -> MapPose:
        raise NotImplementedError

    def tick(self, now: float) -> None:
        raise NotImplementedError

    def next_deadline(self) -> float:
        raise NotImplementedError
