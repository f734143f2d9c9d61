"""The ROS 2 adapter's core: blackmetal payloads in, ROS messages out, and back. Pure and clock-injected.

It is a plain client of the robot's keys: poses become ``/odom`` and
``/tf``, impulses become ``/joint_states``, and ROS ``/cmd_vel`` and
``/estop`` become the JSON messages the gateway already takes, so the
gateway's limits, timeout and emergency stop apply to ROS exactly as to any
other client. Whatever cannot be decoded is reported on ``<prefix>/errors``
with the reason and is never forwarded.

Every input comes with ``now`` (the receiver's monotonic time); what is due
later (summaries of rate-limited error reports) goes out in
:meth:`Ros2Core.tick`, at :meth:`Ros2Core.next_deadline`. No I/O and no
clock read here: :mod:`blackmetal.ros2.host` runs it on a loop, and tests
call it directly.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from blackmetal.robot_model import Encoders
from blackmetal.runtime.reports import ErrorReporter
from schemas import ErrorReport, Keys, PayloadError, Pose, WheelImpulses, decode, encode

from .messages import Frames, RosCodec

#: Joint positions are not integrated across a gap longer than this (s): a lost link is not motion.
MAX_JOINT_GAP_S = 0.5


class Ros2Output(Protocol):
    """Where the core's messages go: CDR on a ROS topic, a payload on a blackmetal key, an error report."""

    def ros(self, topic: str, cdr: bytes) -> None: ...
    def blackmetal(self, key: str, payload: bytes) -> None: ...
    def error(self, message: ErrorReport) -> None: ...


@dataclass(frozen=True, slots=True)
class Ros2Options:
    frames: Frames
    pose_covariance: list[float]
    twist_covariance: list[float]
    publish_tf: bool
    twist_stamped: bool
    joint_names: tuple[str, str]
    wheel_radius: float
    encoders: Encoders
    #: How error reports name the ROS inputs: the Zenoh key each arrives on.
    cmd_vel_key: str = "cmd_vel"
    estop_key: str = "estop"


class WheelJoints:
    """Wheel angles (rad) integrated from wheel speeds, trapezoid rule, never across a gap."""

    def __init__(self, encoders: Encoders, radius: float) -> None:
        self.encoders = encoders
        self.radius = radius
        self.positions = [0.0, 0.0]
        self.velocities = [0.0, 0.0]
        self._last_time: float | None = None

    def feed(self, sample: WheelImpulses) -> None:
        left, right = self.encoders.to_speeds(float(sample.left), float(sample.right))
        velocities = [left / self.radius, right / self.radius]
        now = sample.mono if sample.mono is not None else sample.stamp
        if self._last_time is not None:
            dt = now - self._last_time
            if 0.0 < dt <= MAX_JOINT_GAP_S:
                for i in (0, 1):
                    self.positions[i] += 0.5 * (self.velocities[i] + velocities[i]) * dt
        self._last_time = now
        self.velocities = velocities


class Ros2Core:
    """Translates between the robot's keys and ROS topics (topic names relative to the node's namespace)."""

    def __init__(
        self,
        options: Ros2Options,
        keys: Keys,
        output: Ros2Output,
        codec: RosCodec,
        wallclock: Callable[[], float] = time.time,
    ) -> None:
        self.options = options
        self.keys = keys
        self.output = output
        self.codec = codec
        self.reporter = ErrorReporter("ros2", output.error, wallclock)
        self.joints = WheelJoints(options.encoders, options.wheel_radius)

    # --------------------------------------------------------------- blackmetal -> ROS
    def on_pose(self, payload: bytes, now: float) -> None:
        try:
            pose = decode(Pose, payload)
        except PayloadError as exc:
            self.reporter.report(self.keys.pose, str(exc), exc.excerpt, now=now)
            return
        o = self.options
        self.output.ros("odom", self.codec.odometry(pose, o.frames, o.pose_covariance, o.twist_covariance))
        if o.publish_tf:
            self.output.ros("tf", self.codec.transform(pose, o.frames))

    def on_impulses(self, payload: bytes, now: float) -> None:
        try:
            sample = decode(WheelImpulses, payload)
        except PayloadError as exc:
            self.reporter.report(self.keys.impulses, str(exc), exc.excerpt, now=now)
            return
        self.joints.feed(sample)
        cdr = self.codec.joint_state(sample.stamp, list(self.options.joint_names), self.joints.positions, self.joints.velocities)
        self.output.ros("joint_states", cdr)

    # --------------------------------------------------------------- ROS -> blackmetal
    def on_cmd_vel(self, cdr: bytes, now: float) -> None:
        try:
            twist = self.codec.twist(cdr, stamped=self.options.twist_stamped)
        except PayloadError as exc:
            self.reporter.report(self.options.cmd_vel_key, str(exc), exc.excerpt, now=now)
            return
        self.output.blackmetal(self.keys.cmd_vel, encode(twist))

    def on_estop(self, cdr: bytes, now: float) -> None:
        try:
            estop = self.codec.estop(cdr)
        except PayloadError as exc:
            self.reporter.report(self.options.estop_key, str(exc), exc.excerpt, now=now)
            return
        self.output.blackmetal(self.keys.estop, encode(estop))

    # --------------------------------------------------------------- timers
    def tick(self, now: float) -> None:
        """Publish what is due at ``now``: summaries of rate-limited error reports."""
        self.reporter.tick(now)

    def next_deadline(self) -> float:
        """When :meth:`tick` has something to do (inf: nothing until the next input)."""
        return self.reporter.next_deadline()
