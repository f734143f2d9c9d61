"""The odometry service's core: impulse payloads in, poses and error reports out, between thin edges.

Runs on one asyncio loop; the Zenoh edge hands payloads and queries over
(:mod:`blackmetal.runtime.edge`). No I/O here: tests call it directly.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from blackmetal.runtime.reports import ErrorReporter
from schemas import ErrorReport, Keys, PayloadError, Pose, PoseReset, WheelImpulses, decode, excerpt

from .core import Odometry, OdometryParams
from .errors import OdometryError, SampleRejected


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
        keys: Keys,
        output: OdometryOutput,
        clock: Callable[[], float] = time.monotonic,
        wallclock: Callable[[], float] = time.time,
    ) -> None:
        self.odometry = Odometry(params)
        self.keys = keys
        self.output = output
        self.clock = clock
        self.reporter = ErrorReporter("odometry", output.error, clock, wallclock)
        self.rejected = 0

    def on_impulses(self, payload: bytes) -> None:
        try:
            sample = decode(WheelImpulses, payload)
        except PayloadError as exc:
            self.reject(self.keys.impulses, str(exc), exc.excerpt)
            return
        try:
            pose = self.odometry.feed(sample, arrival=self.clock())
        except SampleRejected as exc:
            self.reject(self.keys.impulses, str(exc), excerpt(payload))
            return
        self.output.pose(pose)
        while self.odometry.events:
            self.reporter.report(self.keys.impulses, self.odometry.events.pop(0))

    def on_reset(self, payload: bytes | None) -> Pose:
        """Reset to zero, or to the pose in the payload; PayloadError (reported) if it is not a usable pose."""
        try:
            target = PoseReset() if not payload or not payload.strip() else decode(PoseReset, payload)
            try:
                return self.odometry.reset(target.x, target.y, target.yaw)
            except OdometryError as exc:
                raise PayloadError("PoseReset", str(exc), excerpt(payload or b"")) from None
        except PayloadError as exc:
            self.reject(self.keys.odometry_reset, str(exc), exc.excerpt)
            raise

    def on_dropped(self, count: int) -> None:
        """``count`` impulse samples were dropped before they could be handled (the input is bounded)."""
        self.reporter.report(
            self.keys.impulses, f"{count} impulse samples dropped: the odometry fell behind its input (oldest dropped first)"
        )

    def latest(self) -> Pose:
        return self.odometry.pose()

    def reject(self, key: str, reason: str, snippet: str = "") -> None:
        self.rejected += 1
        self.reporter.report(key, reason, snippet)
