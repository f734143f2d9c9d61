"""The navigation's asyncio host: stamps each input with the clock, hands it to the core, and pokes the
:class:`~blackmetal.runtime.driver.CoreTimer` that runs the core's tick (feedback, stale pose and link checks).

Only the loop touches the core (the odometry's shape: no core lock), so every input reaches it through the edge's
intake or, in a fleet, the loop's drain of the pose rings. Every decision is the core's.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from typing import Any

from blackmetal.runtime.driver import CoreTimer
from blackmetal.schemas import GatewayParams, MapPose, NavCancelReply, NavGoalReply, NavResult, ParamsSetReply

from .core import NavCore

#: Poses poke the core's timer at most this often (s); every other input pokes it at once.
POSE_POKE_S = 0.05


class NavHost:
    """Runs one robot's :class:`NavCore` on the loop.

    ``supervised`` (a fleet's robot): a bug in handling it (an input, a tick) ends :meth:`run` with the exception, for
    the fleet to start this robot again from zero; else it goes to the loop's exception handler and the service goes on.
    """

    def __init__(self, core: NavCore, clock: Callable[[], float] = time.monotonic, *, supervised: bool = False) -> None:
        self.core = core
        self.clock = clock
        self.supervised = supervised
        self.timer = CoreTimer(core, clock, on_error=self.fail if supervised else None)
        self._failure: asyncio.Future[None] | None = None
        self._next_pose_poke = -math.inf

    # telemetry: each poke moves the timer only when the core's deadline came earlier
    def on_pose(self, payload: bytes) -> None:
        """A pose moves the core's deadlines later (the stale-pose one), seldom earlier (a report's summary): the timer
        is poked at most every POSE_POKE_S, not at 50 Hz, and such a deadline is met at most that much later."""
        now = self.clock()
        self.core.on_pose(payload, now)
        if now >= self._next_pose_poke:
            self._next_pose_poke = now + POSE_POKE_S
            self.timer.poke()

    def on_health(self, payload: bytes) -> None:
        self.core.on_health(payload, self.clock())
        self.timer.poke()

    def on_driver(self, payload: bytes) -> None:
        self.core.on_driver(payload, self.clock())
        self.timer.poke()

    def on_gateway_params(self, payload: bytes) -> None:
        self.core.on_gateway_params(payload, self.clock())
        self.timer.poke()

    def on_wheel_move_reply(self, payload: bytes) -> None:
        self.core.on_wheel_move_reply(payload, self.clock())
        self.timer.poke()

    def on_wheel_position(self, payload: bytes) -> None:
        self.core.on_wheel_position(payload, self.clock())
        self.timer.poke()

    def on_alive(self, role: str, alive: bool) -> None:
        self.core.on_alive(role, alive, self.clock())
        self.timer.poke()

    # queries: the core never raises for a bad payload (set_pose: PayloadError, reported, for the edge to reply)
    def on_goal(self, payload: bytes | None) -> NavGoalReply:
        try:
            return self.core.on_goal(payload, self.clock())
        finally:
            self.timer.poke()

    def on_move(self, payload: bytes | None) -> NavGoalReply:
        try:
            return self.core.on_move(payload, self.clock())
        finally:
            self.timer.poke()

    def on_cancel(self, payload: bytes | None) -> NavCancelReply:
        try:
            return self.core.on_cancel(payload, self.clock())
        finally:
            self.timer.poke()

    def on_result(self, payload: bytes | None) -> NavResult:
        try:
            return self.core.on_result(payload, self.clock())
        finally:
            self.timer.poke()

    def on_set_pose(self, payload: bytes | None) -> MapPose:
        try:
            return self.core.on_set_pose(payload, self.clock())
        finally:
            self.timer.poke()

    def on_params_set(self, payload: bytes | None) -> ParamsSetReply:
        try:
            return self.core.on_params_set(payload, self.clock())
        finally:
            self.timer.poke()

    def params(self, _payload: bytes | None = None) -> GatewayParams:
        return self.core.params()

    def map_pose(self, _payload: bytes | None = None) -> MapPose:
        return self.core.map_pose()

    def fail(self, exc: BaseException) -> None:
        """A bug in handling this robot: supervised, :meth:`run` ends with it; else the loop's handler reports it."""
        self.timer.stop()
        if self.supervised and self._failure is not None and not self._failure.done():
            self._failure.set_exception(exc)
            return
        if not self.supervised:
            asyncio.get_running_loop().call_exception_handler({"message": "the navigation core failed", "exception": exc})

    def on_error(self) -> Callable[[BaseException], None] | None:
        """What the intake calls with a handler's exception: :meth:`fail` when supervised, else the loop's handler."""
        return self.fail if self.supervised else None

    async def run(self, stop: asyncio.Event) -> None:
        """Run the core's timer until ``stop``; supervised, raise the failure that ended it first."""
        failure: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._failure = failure
        stopped: asyncio.Future[Any] = asyncio.ensure_future(stop.wait())
        try:
            self.timer.start()
            await asyncio.wait({stopped, failure}, return_when=asyncio.FIRST_COMPLETED)
            if failure.done():
                failure.result()
        finally:
            stopped.cancel()
            self.timer.stop()
            self._failure = None
