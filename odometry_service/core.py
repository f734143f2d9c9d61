"""The odometry service's core: impulse payloads in, poses and error reports out. Pure and clock-injected.

Every input comes with ``now`` (the receiver's monotonic time); what is due later goes out in :meth:`OdometryCore.tick`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import ErrorReport, Keys, PayloadError, Pose, PoseReset, WheelImpulses, decode, excerpt

from .errors import OdometryError, SampleRejected
from .integrator import Odometry
from .params import OdometryParams

#: Dropped input is reported at most this often (s), the count summed over the period.
DROPPED_REPORT_PERIOD_S = 1.0


#: Where the odometry's messages go (its edge routes each by type: :meth:`ZenohEdge.publish`).
OdometryOutput = Callable[[Pose | ErrorReport], None]


class OdometryCore:
    """Turns live impulse payloads (``mono`` and ``source`` required) into published poses; reports what it rejects."""

    def __init__(self, params: OdometryParams, keys: Keys, output: OdometryOutput, wallclock: Callable[[], float] = time.time) -> None:
        self.odometry = Odometry(params, live=True)
        self.keys = keys
        self.output = output
        self.reporter = ErrorReporter("odometry", output, wallclock)
        self.rejected = 0
        self._dropped = 0  # dropped samples not yet reported
        self._dropped_due = -math.inf  # when they may be reported

    def on_impulses(self, payload: bytes, now: float) -> None:
        """One impulse sample, arrived at ``now``: a pose published, or a report of why not."""
        try:
            sample = decode(WheelImpulses, payload)
        except PayloadError as exc:
            self.reject(self.keys.impulses, str(exc), exc.excerpt, now=now)
            return
        try:
            pose = self.odometry.feed(sample, arrival=now)
        except SampleRejected as exc:
            self.reject(self.keys.impulses, str(exc), excerpt(payload), now=now)
            return
        self.output(pose)
        while self.odometry.events:
            self.reporter.report(self.keys.impulses, self.odometry.events.pop(0), now=now)

    def on_reset(self, payload: bytes | None, now: float) -> Pose:
        """Reset to zero, or to the pose in the payload; PayloadError (reported) if it is not a usable pose."""
        try:
            target = PoseReset() if not payload or not payload.strip() else decode(PoseReset, payload)
            try:
                return self.odometry.reset(target.x, target.y, target.yaw)
            except OdometryError as exc:
                raise PayloadError("PoseReset", str(exc), excerpt(payload or b"")) from None
        except PayloadError as exc:
            self.reject(self.keys.odometry_reset, str(exc), exc.excerpt, now=now)
            raise

    def on_dropped(self, count: int, now: float) -> None:
        """Input dropped (it is bounded): reported in :meth:`tick`, summed over DROPPED_REPORT_PERIOD_S, so an
        overload does not spend the impulse key's report budget."""
        self._dropped += max(count, 0)

    def latest(self) -> Pose:
        return self.odometry.pose()

    def reject(self, key: str, reason: str, snippet: str = "", *, now: float) -> None:
        self.rejected += 1
        self.reporter.report(key, reason, snippet, now=now)

    def tick(self, now: float) -> None:
        """Publish what is due at ``now``: the count of dropped samples, summaries of rate-limited reports."""
        if self._dropped and now >= self._dropped_due:
            reason = f"{self._dropped} impulse samples dropped: the odometry fell behind its input (oldest dropped first)"
            self.reporter.report(self.keys.impulses, reason, now=now)
            self._dropped = 0
            self._dropped_due = now + DROPPED_REPORT_PERIOD_S
        self.reporter.tick(now)

    def next_deadline(self) -> float:
        """When :meth:`tick` has something to do (inf: nothing until the next input)."""
        dropped = self._dropped_due if self._dropped else math.inf
        return min(dropped, self.reporter.next_deadline())
