"""The odometry service's core loop: impulses in, poses out, between thin edges.

All work happens on one thread that drains a queue; the Zenoh edge only puts
payloads and queries on that queue from its callbacks.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from gateway.ratelimit import ReportLimiter
from schemas import ErrorReport, PayloadError, Pose, PoseReset, WheelImpulses, decode, excerpt

from .core import Odometry, OdometryParams
from .errors import SampleRejected


class OdometryOutput(Protocol):
    def pose(self, message: Pose) -> None: ...
    def error(self, message: ErrorReport) -> None: ...


@dataclass
class RecordingOdometryOutput:
    poses: list[Pose] = field(default_factory=list)
    errors: list[ErrorReport] = field(default_factory=list)

    def pose(self, message: Pose) -> None:
        self.poses.append(message)

    def error(self, message: ErrorReport) -> None:
        self.errors.append(message)


class OdometryService:
    """Turns impulse payloads into published poses; reports everything it rejects."""

    def __init__(
        self,
        params: OdometryParams,
        prefix: str,
        output: OdometryOutput,
        clock: Callable[[], float] = time.monotonic,
        wallclock: Callable[[], float] = time.time,
    ) -> None:
        self.odometry = Odometry(params)
        self.prefix = prefix
        self.output = output
        self.clock = clock
        self.wallclock = wallclock
        self.limiter = ReportLimiter()
        self.rejected = 0
        self._impulses_key = f"{prefix}/wheels/impulses"

    def on_impulses(self, payload: bytes) -> None:
        try:
            sample = decode(WheelImpulses, payload)
        except PayloadError as exc:
            self.reject(self._impulses_key, str(exc), exc.excerpt)
            return
        try:
            pose = self.odometry.feed(sample)
        except SampleRejected as exc:
            self.reject(self._impulses_key, str(exc), excerpt(payload))
            return
        self.output.pose(pose)
        while self.odometry.events:
            self.report(self._impulses_key, self.odometry.events.pop(0))

    def on_reset(self, payload: bytes | None) -> Pose:
        """Reset to zero, or to the pose in the payload; PayloadError if it is not one."""
        target = PoseReset() if not payload or not payload.strip() else decode(PoseReset, payload)
        return self.odometry.reset(target.x, target.y, target.yaw)

    def latest(self) -> Pose:
        return self.odometry.pose()

    def reject(self, key: str, reason: str, snippet: str = "") -> None:
        self.rejected += 1
        self.report(key, reason, snippet)

    def report(self, key: str, reason: str, snippet: str = "") -> None:
        admitted, suppressed = self.limiter.admit(key, self.clock())
        if admitted:
            self.output.error(
                ErrorReport(
                    stamp=self.wallclock(), source="odometry", key=key, reason=reason, excerpt=snippet, suppressed=suppressed
                )
            )

    def flush_suppressed(self) -> None:
        for key, suppressed in self.limiter.due_summaries(self.clock()):
            self.output.error(
                ErrorReport(
                    stamp=self.wallclock(),
                    source="odometry",
                    key=key,
                    reason=f"{suppressed} more reports on {key} were rate-limited",
                    suppressed=suppressed,
                )
            )
