"""The Foxglove view's core: what it shows, built from the robot's payloads: Foxglove's own types where a panel needs them, JSON elsewhere.

| Foxglove topic | schema | from |
|---|---|---|
| ``/pose`` | ``foxglove.PoseInFrame`` in ``odom`` | ``<prefix>/pose`` |
| ``/tf`` | ``foxglove.FrameTransform`` odom -> base_link (the 3D panel follows it) | ``<prefix>/pose`` |
| ``/path`` | ``foxglove.PosesInFrame``, the last ``path_length`` poses, 5 Hz | ``<prefix>/pose`` |
| ``/truth/pose``, ``/truth/path`` | the same for the simulator's true pose | ``<prefix>/sim/truth`` |
| ``/odometry`` | blackmetal ``Pose`` (JSON, with v and w for plots) | ``<prefix>/pose`` |
| ``/wheels`` | wheel speeds in m/s and impulses/s (JSON) | ``<prefix>/wheels/impulses`` |
| ``/status``, ``/health``, ``/errors`` | blackmetal JSON messages, as published | their keys |
| ``/log`` | ``foxglove.Log``, one per error report (the Log panel) | ``<prefix>/errors`` |

Payloads that do not decode are skipped; the view never
crashes on what a key carries. No clock and no timers: the paths are
throttled on the messages' own stamps, so nothing is due later and the view
has no ``tick``/``next_deadline`` (its host needs no deadline timer).
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Callable
from typing import Any

from blackmetal.robot_model import Encoders
from schemas import ErrorReport, GatewayHealth, Keys, PayloadError, Pose, RobotStatus, WheelImpulses, decode, json_schemas, stamp_parts

#: How often the paths are sent (s of message time): a path is big, the pose is not.
PATH_PERIOD_S = 0.2

WHEELS_SCHEMA: dict[str, Any] = {
    "title": "WheelSpeeds",
    "description": "blackmetal wheel speeds, from <prefix>/wheels/impulses",
    "type": "object",
    "properties": {
        "stamp": {"type": "number"},
        "left_mps": {"type": "number"},
        "right_mps": {"type": "number"},
        "left_impulses": {"type": "integer"},
        "right_impulses": {"type": "integer"},
    },
    "required": ["stamp", "left_mps", "right_mps", "left_impulses", "right_impulses"],
}


def timestamp(stamp: float) -> Any:
    from foxglove.messages import Timestamp

    sec, nsec = stamp_parts(stamp)
    return Timestamp(sec=sec, nsec=nsec)


def _pose(pose: Pose) -> Any:
    from foxglove.messages import Pose as FoxPose
    from foxglove.messages import Quaternion, Vector3

    q = pose.orientation
    return FoxPose(position=Vector3(x=pose.x, y=pose.y, z=0.0), orientation=Quaternion(x=q.x, y=q.y, z=q.z, w=q.w))


class Trail:
    """A bounded path of poses, sent at most every PATH_PERIOD_S."""

    def __init__(self, length: int) -> None:
        self.poses: deque[Pose] = deque(maxlen=length)
        self._last_sent = -1e18

    def add(self, pose: Pose) -> bool:
        """Add a pose; True when the path is due to be sent."""
        self.poses.append(pose)
        if pose.stamp - self._last_sent >= PATH_PERIOD_S or pose.stamp < self._last_sent:
            self._last_sent = pose.stamp
            return True
        return False


class LiveView:
    """Declares the view's channels on the current Foxglove context and logs into them from the robot's payloads."""

    def __init__(
        self, keys: Keys, frame: str = "odom", base: str = "base_link", path_length: int = 2000, encoders: Encoders | None = None
    ) -> None:
        import foxglove
        from foxglove.channels import FrameTransformChannel, LogChannel, PoseInFrameChannel, PosesInFrameChannel

        self.keys = keys
        self.frame, self.base = frame, base
        self.encoders = encoders or Encoders()
        schemas = json_schemas()

        def json_channel(topic: str, schema: dict[str, Any]) -> Any:
            full = foxglove.Schema(name=schema["title"], encoding="jsonschema", data=json.dumps(schema).encode())
            return foxglove.Channel(topic, schema=full, message_encoding="json")

        self.pose = PoseInFrameChannel("/pose")
        self.tf = FrameTransformChannel("/tf")
        self.path = PosesInFrameChannel("/path")
        self.truth = PoseInFrameChannel("/truth/pose")
        self.truth_path = PosesInFrameChannel("/truth/path")
        self.odometry = json_channel("/odometry", schemas["Pose"])
        self.wheels = json_channel("/wheels", WHEELS_SCHEMA)
        self.status = json_channel("/status", schemas["RobotStatus"])
        self.health = json_channel("/health", schemas["GatewayHealth"])
        self.errors = json_channel("/errors", schemas["ErrorReport"])
        self.log = LogChannel("/log")
        self._trail = Trail(path_length)
        self._truth_trail = Trail(path_length)

    def handlers(self) -> dict[str, Callable[[bytes], None]]:
        """Key -> handler of its payloads."""
        k = self.keys
        return {
            k.pose: self.on_pose,
            k.sim_truth: self.on_truth,
            k.impulses: self.on_impulses,
            k.status: lambda p: self._forward(self.status, RobotStatus, p),
            k.health: lambda p: self._forward(self.health, GatewayHealth, p),
            k.errors: self.on_error,
        }

    def _decode(self, message_type: type[Any], payload: bytes) -> Any:
        try:
            return decode(message_type, payload)
        except PayloadError:
            return None

    def _forward(self, channel: Any, message_type: type[Any], payload: bytes) -> None:
        if self._decode(message_type, payload) is not None:
            channel.log(payload)

    def _poses(self, pose: Pose, channel: Any, path_channel: Any, trail: Trail) -> None:
        from foxglove.messages import PoseInFrame, PosesInFrame

        channel.log(PoseInFrame(timestamp=timestamp(pose.stamp), frame_id=self.frame, pose=_pose(pose)))
        if trail.add(pose):
            path_channel.log(PosesInFrame(timestamp=timestamp(pose.stamp), frame_id=self.frame, poses=[_pose(p) for p in trail.poses]))

    def on_pose(self, payload: bytes) -> None:
        from foxglove.messages import FrameTransform, Quaternion, Vector3

        pose = self._decode(Pose, payload)
        if pose is None:
            return
        self._poses(pose, self.pose, self.path, self._trail)
        q = pose.orientation
        self.tf.log(
            FrameTransform(
                timestamp=timestamp(pose.stamp),
                parent_frame_id=self.frame,
                child_frame_id=self.base,
                translation=Vector3(x=pose.x, y=pose.y, z=0.0),
                rotation=Quaternion(x=q.x, y=q.y, z=q.z, w=q.w),
            )
        )
        self.odometry.log(payload)

    def on_truth(self, payload: bytes) -> None:
        pose = self._decode(Pose, payload)
        if pose is not None:
            self._poses(pose, self.truth, self.truth_path, self._truth_trail)

    def on_impulses(self, payload: bytes) -> None:
        sample = self._decode(WheelImpulses, payload)
        if sample is None:
            return
        left, right = self.encoders.to_speeds(float(sample.left), float(sample.right))
        message = {
            "stamp": sample.stamp,
            "left_mps": left,
            "right_mps": right,
            "left_impulses": sample.left,
            "right_impulses": sample.right,
        }
        self.wheels.log(json.dumps(message).encode())

    def on_error(self, payload: bytes) -> None:
        from foxglove.messages import Log, LogLevel

        report = self._decode(ErrorReport, payload)
        if report is None:
            return
        self.errors.log(payload)
        self.log.log(
            Log(timestamp=timestamp(report.stamp), level=LogLevel.Warning, message=f"{report.key}: {report.reason}", name=report.source)
        )
