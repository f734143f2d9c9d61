"""The live view of one robot (:class:`LiveView`): its keys' payloads shown on Foxglove channels (docs/foxglove.md, "Channels").

Payloads that do not decode are skipped; the view never crashes on what a key carries. It has no clock: the
paths are throttled on the messages' own stamps.
"""

from __future__ import annotations

import json
import math
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from blackmetal.robot_model import Encoders, WheelAngles
from blackmetal.schemas import (
    ErrorReport,
    GatewayHealth,
    GatewayParams,
    Keys,
    MapPose,
    NavFeedback,
    PayloadError,
    PlanarPose,
    Pose,
    RobotStatus,
    WheelImpulses,
    decode,
    json_schemas,
    yaw_quaternion,
)

from .channels import ChannelFactory, Kind, Out, fox_pose, foxglove_channel, message_schema, report_log, timestamp, transform, typed
from .diagnostics import DIAGNOSTICS_SCHEMA, diagnostics
from .model import JOINT_STATE_SCHEMA, STRING_SCHEMA, RobotModel, joint_state, turned
from .naming import StatusLevel, robot_frame, robot_namespace

#: How often the paths are sent (s of message time): a path is big, the pose is not.
PATH_PERIOD_S = 0.2
#: ``map -> odom`` and the URDF's fixed joints (``base_footprint -> base_link``) are sent again with the poses this
#: often (s of message time): a client that came late has them soon.
MAP_TF_PERIOD_S = 1.0

_WHEELS = {"stamp": typed("number"), "left_mps": typed("number"), "right_mps": typed("number")}
_WHEELS |= {"left_impulses": typed("integer"), "right_impulses": typed("integer")}
WHEELS_SCHEMA = message_schema("WheelSpeeds", "blackmetal wheel speeds, from <prefix>/wheels/impulses", _WHEELS, list(_WHEELS))

#: Each key the view follows (a :class:`Keys` attribute) -> its handler, and the topics it feeds (under the namespace).
FEEDS = {
    "pose": ("on_pose", ("/pose", "/tf", "/path", "/odometry")),
    "sim_truth": ("on_truth", ("/truth/pose", "/truth/path")),
    "impulses": ("on_impulses", ("/wheels", "/joint_states", "/tf")),
    "status": ("on_status", ("/status",)),
    "health": ("on_health", ("/health", "/diagnostics")),
    "errors": ("on_error", ("/errors", "/log")),
    "nav_feedback": ("on_nav_feedback", ("/nav/feedback", "/nav/goal", "/nav/plan")),
    "nav_map_pose": ("on_map_pose", ("/tf",)),
}


def _planar(pose: PlanarPose) -> Any:
    return fox_pose(Pose(stamp=0.0, x=pose.x, y=pose.y, yaw=pose.yaw, orientation=yaw_quaternion(pose.yaw)))


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
    """The view's channels of one robot, and what each of its keys' payloads shows on them.

    A payload nobody watches (no channel it feeds ``has_sinks``) is not even decoded.
    """

    def __init__(
        self,
        keys: Keys,
        robot_id: str = "",
        path_length: int = 2000,
        encoders: Encoders | None = None,
        tf: Out | None = None,
        channel: ChannelFactory = foxglove_channel,
    ) -> None:
        """``robot_id`` (a fleet's robot): its topics under ``/<id>``, its frames and URDF links under ``<id>/``;
        ``tf``: a transform channel shared with other views (else ``<namespace>/tf``)."""
        self.keys = keys
        self.namespace = ns = robot_namespace(robot_id) if robot_id else ""
        frame_prefix = robot_frame(robot_id, "") if robot_id else ""
        # odom -> base_footprint, as the ROS 2 adapter's /odom says and the URDF's root is (#40: base_link had two parents)
        self.frame, self.base = frame_prefix + "odom", frame_prefix + "base_footprint"
        self.model = RobotModel(frame_prefix, encoders)
        self._angles = WheelAngles(wrap=True)
        schemas = json_schemas()

        self.pose = channel(f"{ns}/pose", Kind.POSE, None)
        self.tf = tf if tf is not None else channel(f"{ns}/tf", Kind.TRANSFORM, None)
        self.tf_topic = "/tf" if tf is not None else f"{ns}/tf"
        self.path = channel(f"{ns}/path", Kind.POSES, None)
        self.truth = channel(f"{ns}/truth/pose", Kind.POSE, None)
        self.truth_path = channel(f"{ns}/truth/path", Kind.POSES, None)
        self.odometry = channel(f"{ns}/odometry", Kind.JSON, schemas["Pose"])
        self.wheels = channel(f"{ns}/wheels", Kind.JSON, WHEELS_SCHEMA)
        self.joint_states = channel(f"{ns}/joint_states", Kind.JSON, JOINT_STATE_SCHEMA)
        self.description_topic = f"{ns}/robot_description"
        self.description = channel(self.description_topic, Kind.JSON, STRING_SCHEMA)
        self.status = channel(f"{ns}/status", Kind.JSON, schemas["RobotStatus"])
        self.health = channel(f"{ns}/health", Kind.JSON, schemas["GatewayHealth"])
        self.diagnostics = channel(f"{ns}/diagnostics", Kind.JSON, DIAGNOSTICS_SCHEMA)
        self.errors = channel(f"{ns}/errors", Kind.JSON, schemas["ErrorReport"])
        self.log = channel(f"{ns}/log", Kind.LOG, None)
        self.nav_feedback = channel(f"{ns}/nav/feedback", Kind.JSON, schemas["NavFeedback"])
        #: The goal being driven to (or the last one), in its frame: ``map`` or the robot's ``odom``.
        self.nav_goal = channel(f"{ns}/nav/goal", Kind.POSE, None)
        #: The way there: the robot and its goal, the straight line the controller drives (it turns, drives, turns).
        self.nav_plan = channel(f"{ns}/nav/plan", Kind.POSES, None)
        self._map_pose: MapPose | None = None
        self._map_sent = -math.inf
        self._trail = Trail(path_length)
        self._truth_trail = Trail(path_length)

    def feeds(self) -> dict[str, set[str]]:
        """Key -> the topics its payloads are shown on (the host subscribes to a key while one of them is watched)."""
        topic = {t: self.tf_topic if t == "/tf" else f"{self.namespace}{t}" for _, topics in FEEDS.values() for t in topics}
        return {getattr(self.keys, key): {topic[t] for t in topics} for key, (_, topics) in FEEDS.items()}

    def handlers(self) -> dict[str, Callable[[bytes], None]]:
        return {getattr(self.keys, key): getattr(self, handler) for key, (handler, _) in FEEDS.items()}

    def _decode(self, message_type: type[Any], payload: bytes) -> Any:
        try:
            return decode(message_type, payload)
        except PayloadError:
            return None

    def _take(self, message_type: type[Any], payload: bytes, *channels: Out) -> tuple[Any, list[bool]]:
        """The payload decoded and which of ``channels`` anyone takes; (None, ...) when nobody does or it does not decode."""
        wants = [channel.has_sinks() for channel in channels]
        return (self._decode(message_type, payload) if any(wants) else None), wants

    def _poses(self, pose: Pose, channel: Out, path_channel: Out, trail: Trail) -> None:
        from foxglove.messages import PoseInFrame, PosesInFrame

        if channel.has_sinks():
            channel.log(PoseInFrame(timestamp=timestamp(pose.stamp), frame_id=self.frame, pose=fox_pose(pose)))
        if trail.add(pose) and path_channel.has_sinks():
            path_channel.log(PosesInFrame(timestamp=timestamp(pose.stamp), frame_id=self.frame, poses=[fox_pose(p) for p in trail.poses]))

    def on_pose(self, payload: bytes) -> None:
        pose, wants = self._take(Pose, payload, self.pose, self.path, self.tf, self.odometry)
        if pose is None:
            return
        self._poses(pose, self.pose, self.path, self._trail)
        if wants[2]:
            q = pose.orientation
            self.tf.log(transform(pose.stamp, self.frame, self.base, (pose.x, pose.y, 0.0), (q.x, q.y, q.z, q.w)))
            if not 0.0 <= pose.stamp - self._map_sent < MAP_TF_PERIOD_S:
                self._send_slow(pose.stamp)
        if wants[3]:
            self.odometry.log(payload)

    def on_truth(self, payload: bytes) -> None:
        pose, _ = self._take(Pose, payload, self.truth, self.truth_path)
        if pose is not None:
            self._poses(pose, self.truth, self.truth_path, self._truth_trail)

    def on_status(self, payload: bytes) -> None:
        if self.status.has_sinks() and self._decode(RobotStatus, payload) is not None:
            self.status.log(payload)

    def _echo(self, message_type: type[Any], payload: bytes, raw: Out, derived: Out, build: Callable[[Any], Any]) -> None:
        """The payload as published on ``raw``, and ``build(message)`` on ``derived``: each only when someone takes it."""
        message, (shows, derives) = self._take(message_type, payload, raw, derived)
        if message is None:
            return
        if shows:
            raw.log(payload)
        if derives:
            derived.log(build(message))

    def on_health(self, payload: bytes) -> None:
        self._echo(GatewayHealth, payload, self.health, self.diagnostics, lambda h: json.dumps(diagnostics(h, self.keys.prefix)).encode())

    def on_impulses(self, payload: bytes) -> None:
        sample, (speeds, joints, turns) = self._take(WheelImpulses, payload, self.wheels, self.joint_states, self.tf)
        if sample is None:
            return
        model = self.model
        self._angles.feed(sample, model.encoders, model.body.wheel_radius)
        if speeds:
            left, right = model.encoders.to_speeds(float(sample.left), float(sample.right))
            message = dict(zip(_WHEELS, (sample.stamp, left, right, sample.left, sample.right), strict=True))  # the schema's order
            self.wheels.log(json.dumps(message).encode())
        if joints:
            self.joint_states.log(json.dumps(joint_state(model, self._angles, sample.stamp)).encode())
        if turns:
            for joint, angle in ((model.left, self._angles.positions[0]), (model.right, self._angles.positions[1])):
                if joint is not None:
                    xyz, q = turned(joint, angle)
                    self.tf.log(transform(sample.stamp, joint.parent, joint.child, xyz, q))

    def on_error(self, payload: bytes) -> None:
        self._echo(ErrorReport, payload, self.errors, self.log, report_log)

    def _send_slow(self, stamp: float) -> None:
        """What changes seldom or never, with the poses now and then: the URDF's fixed joints and ``map -> odom``."""
        for joint in self.model.fixed:
            self.tf.log(transform(stamp, joint.parent, joint.child, joint.origin, (0.0, 0.0, 0.0, 1.0)))
        if self._map_pose is not None:
            self._send_map(stamp)
        self._map_sent = stamp

    def _send_map(self, stamp: float) -> None:
        placed = self._map_pose
        assert placed is not None
        half = placed.yaw / 2
        self.tf.log(transform(stamp, placed.map, self.frame, (placed.x, placed.y, 0.0), (0.0, 0.0, math.sin(half), math.cos(half))))

    def on_map_pose(self, payload: bytes) -> None:
        """Where the navigation service places the odometry frame on the map: ``map -> odom`` on the view's /tf."""
        placed = self._decode(MapPose, payload)  # rare: kept even while nobody watches /tf, for when someone does
        if placed is not None:
            self._map_pose = placed
            if self.tf.has_sinks():
                self._send_map(placed.stamp)

    def on_nav_feedback(self, payload: bytes) -> None:
        """The navigation service's feedback as it says it, and the goal it drives to as a pose in the goal's frame."""
        feedback, (shows, goal, plan) = self._take(NavFeedback, payload, self.nav_feedback, self.nav_goal, self.nav_plan)
        if feedback is None:
            return
        if shows:
            self.nav_feedback.log(payload)
        frame = self.frame if feedback.goal.frame == "odom" else feedback.goal.frame
        if goal:
            from foxglove.messages import PoseInFrame

            self.nav_goal.log(PoseInFrame(timestamp=timestamp(feedback.stamp), frame_id=frame, pose=_planar(feedback.goal)))
        if plan:
            from foxglove.messages import PosesInFrame

            way = [_planar(feedback.pose), _planar(feedback.goal)]
            self.nav_plan.log(PosesInFrame(timestamp=timestamp(feedback.stamp), frame_id=frame, poses=way))

    def nav_event(self, level: StatusLevel, message: str) -> None:
        """A line for the robot's /log: the navigation service's answer to what a client asked (or a clicked point)."""
        if self.log.has_sinks():
            from foxglove.messages import Log, LogLevel

            kind = {StatusLevel.INFO: LogLevel.Info, StatusLevel.WARNING: LogLevel.Warning}.get(level, LogLevel.Error)
            self.log.log(Log(timestamp=timestamp(time.time()), level=kind, message=message, name="nav"))

    def on_params(self, params: GatewayParams) -> None:
        """The gateway's parameters: a new wheel geometry re-sends the URDF to whoever shows it."""
        if self.model.on_params(params):
            self.describe()

    def describe(self) -> None:
        """Send the URDF on ``/robot_description`` (to every subscriber: on a new subscription, and when it changes)."""
        if self.description.has_sinks():
            self.description.log(self.model.description())
