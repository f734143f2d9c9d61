"""Open-RMF free_fleet's Nav2 robot adapter, as it talks to one robot over plain Zenoh: the independent client of tests/integration/test_open_rmf.py.

Written from free_fleet's sources (https://github.com/open-rmf/free_fleet, branch ``main``, commit
``002505f``: ``free_fleet_adapter/free_fleet_adapter/nav2_robot_adapter.py``, ``fleet_adapter.py``,
``free_fleet/free_fleet/ros2_types.py``, ``utils.py``), never from our adapter: free_fleet's own code
stays out of this repository, so the message types below are written here with pycdr2 (what
free_fleet uses) in the layouts its ``ros2_types.py`` gives them, and
tests/contract/test_navigation_clients.py holds their bytes to the genuine ``.msg`` / ``.action``
definitions in tests/ros2_interfaces/. What it reproduces, call for call:

* keys: ``namespacify(name, robot)`` = ``<robot>/<name>``, the plain key format of
  zenoh-bridge-ros2dds with the robot's name as its namespace (no domain, type or hash);
* ``Nav2TfHandler``: a subscriber on ``<robot>/tf`` (never ``tf_static``), each transform put into a
  tf2 buffer with both frame ids namespaced by the robot's name, and ``lookup_transform(<robot>/map,
  <robot>/base_footprint, Time())``: the latest common time of the chain, as tf2 computes it
  (tests/tf2_buffer.py is that part of tf2, 10 s cache);
* initialisation: the pose tried once a second (``create_timer(1, ...)``) until ``init_timeout_sec``
  (default 10 s), then ``RuntimeError('Timeout trying to initialize robot [...]')``;
* ``<robot>/battery_state``: ``percentage`` only, 1.0 until a sample arrives;
* ``<robot>/navigate_to_pose/_action/feedback``: the whole FeedbackMessage kept with the second it
  arrived (``ExecutionFeedback``), used to skip ``get_result`` while ``estimated_time_remaining``
  says the goal is not due;
* ``navigate``: a cancel-all first if a goal is held (``_request_stop``), then ``session.get`` on
  ``send_goal`` with ``NavigateToPose_SendGoal_Request`` (16 random bytes of goal id, the pose stamped
  now in ``map_frame``, ``behavior_tree=''``), ``timeout=service_call_timeout_sec`` (None: Zenoh's
  default), each reply read as ``NavigateToPose_SendGoal_Response`` (``accepted``);
* ``_is_navigation_done``: ``get_result`` with the goal id; only the ``status`` byte of the reply is
  read (free_fleet's response type has no result field);
* ``stop`` / ``_handle_stop_navigation``: ``cancel_goal`` with a zero goal id and zero stamp (cancel
  all, per action_msgs/srv/CancelGoal.srv), each reply read as ``CancelGoal_Response``.

Every call is timed (``calls``), every reply that could not be read is kept (``errors``) so a test can
say what went wrong where free_fleet would only log it.
"""

# no `from __future__ import annotations`: pycdr2 resolves the field types of its IdlStructs at run time
import math
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import zenoh
from pycdr2 import IdlStruct
from pycdr2.types import array, float32, float64, int8, int16, int32, sequence, uint8, uint32
from tf2_buffer import TfBuffer, TfLookupError


# ------------------------------------------------------------------ the messages, laid out as free_fleet's ros2_types.py lays them out
@dataclass
class Time(IdlStruct):
    """builtin_interfaces/msg/Time."""

    sec: int32
    nanosec: uint32


@dataclass
class Duration(IdlStruct):
    """builtin_interfaces/msg/Duration."""

    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct):
    """std_msgs/msg/Header."""

    stamp: Time
    frame_id: str


@dataclass
class Point(IdlStruct):
    """geometry_msgs/msg/Point."""

    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct):
    """geometry_msgs/msg/Quaternion (w = 1 by default, as the .msg says)."""

    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Pose(IdlStruct):
    """geometry_msgs/msg/Pose."""

    position: Point
    orientation: Quaternion


@dataclass
class PoseStamped(IdlStruct):
    """geometry_msgs/msg/PoseStamped."""

    header: Header
    pose: Pose


@dataclass
class SendGoalRequest(IdlStruct):
    """nav2_msgs/action/NavigateToPose_SendGoal_Request: the goal id's UUID flattened to its 16 bytes, the goal's fields inline."""

    goal_id: array[uint8, 16]
    pose: PoseStamped
    behavior_tree: str


@dataclass
class SendGoalResponse(IdlStruct):
    """nav2_msgs/action/NavigateToPose_SendGoal_Response."""

    accepted: bool
    stamp: Time


@dataclass
class GetResultRequest(IdlStruct):
    """nav2_msgs/action/NavigateToPose_GetResult_Request."""

    goal_id: array[uint8, 16]


@dataclass
class GetResultResponse(IdlStruct):
    """nav2_msgs/action/NavigateToPose_GetResult_Response as free_fleet reads it: the status byte, the result left unread."""

    status: int8


class GoalStatus(IntEnum):
    """action_msgs/msg/GoalStatus's constants."""

    UNKNOWN = 0
    ACCEPTED = 1
    EXECUTING = 2
    CANCELING = 3
    SUCCEEDED = 4
    CANCELED = 5
    ABORTED = 6


@dataclass
class FeedbackMessage(IdlStruct):
    """nav2_msgs/action/NavigateToPose_FeedbackMessage (free_fleet's ``NavigateToPose_Feedback``): goal id, then the feedback inline."""

    goal_id: array[uint8, 16]
    current_pose: PoseStamped
    navigation_time: Duration
    estimated_time_remaining: Duration
    number_of_recoveries: int16
    distance_remaining: float32


@dataclass
class Vector3(IdlStruct):
    """geometry_msgs/msg/Vector3."""

    x: float64
    y: float64
    z: float64


@dataclass
class Transform(IdlStruct):
    """geometry_msgs/msg/Transform."""

    translation: Vector3
    rotation: Quaternion


@dataclass
class TransformStamped(IdlStruct):
    """geometry_msgs/msg/TransformStamped."""

    header: Header
    child_frame_id: str
    transform: Transform


@dataclass
class TFMessage(IdlStruct):
    """tf2_msgs/msg/TFMessage."""

    transforms: sequence[TransformStamped]


@dataclass
class UUID(IdlStruct):
    """unique_identifier_msgs/msg/UUID."""

    uuid: array[uint8, 16]


@dataclass
class GoalInfo(IdlStruct):
    """action_msgs/msg/GoalInfo."""

    goal_id: UUID
    stamp: Time


@dataclass
class CancelGoalRequest(IdlStruct):
    """action_msgs/srv/CancelGoal_Request."""

    goal_info: GoalInfo


@dataclass
class CancelGoalResponse(IdlStruct):
    """action_msgs/srv/CancelGoal_Response."""

    return_code: int8
    goals_canceling: sequence[GoalInfo]


@dataclass
class BatteryState(IdlStruct):
    """sensor_msgs/msg/BatteryState."""

    header: Header
    voltage: float32
    temperature: float32
    current: float32
    charge: float32
    capacity: float32
    design_capacity: float32
    percentage: float32
    power_supply_status: uint8
    power_supply_health: uint8
    power_supply_technology: uint8
    present: bool
    cell_voltage: sequence[float32]
    cell_temperature: sequence[float32]
    location: str
    serial_number: str


def cancel_all_request() -> CancelGoalRequest:
    """free_fleet's ``make_nav2_cancel_all_goals_request``: goal id zero and stamp zero cancel every goal."""
    return CancelGoalRequest(goal_info=GoalInfo(UUID(uuid=[0] * 16), Time(sec=0, nanosec=0)))


def _prepare_types() -> None:
    """Have pycdr2 build each type's (de)serializer now, on one thread: it builds them lazily, and two Zenoh
    callbacks reading a type for the first time at once (two robots' tf) can find it half built. free_fleet would
    lose that one sample (its tf callback logs the error at debug level); here nothing is lost."""
    stamp = Time(sec=0, nanosec=0)
    pose = PoseStamped(Header(stamp, ""), Pose(Point(0.0, 0.0, 0.0), Quaternion()))
    samples = [
        TFMessage([TransformStamped(Header(stamp, ""), "", Transform(Vector3(0.0, 0.0, 0.0), Quaternion()))]),
        FeedbackMessage([0] * 16, pose, Duration(0, 0), Duration(0, 0), 0, 0.0),
        BatteryState(Header(stamp, ""), *[0.0] * 7, 0, 0, 0, False, [], [], "", ""),
        SendGoalRequest([0] * 16, pose, ""),
        SendGoalResponse(False, stamp),
        GetResultRequest([0] * 16),
        GetResultResponse(0),
        CancelGoalRequest(GoalInfo(UUID([0] * 16), stamp)),
        CancelGoalResponse(0, [GoalInfo(UUID([0] * 16), stamp)]),
    ]
    for sample in samples:
        type(sample).deserialize(sample.serialize())


def namespacify(base_name: str, namespace: str) -> str:
    """free_fleet's key and frame naming: ``<namespace>/<base_name>``, or the base name alone without a namespace."""
    return base_name if not namespace else f"{namespace}/{base_name}"


def quaternion_from_yaw(yaw: float) -> tuple[float, float, float, float]:
    """tf_transformations.quaternion_from_euler(0, 0, yaw) as (x, y, z, w)."""
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """The yaw of tf_transformations.euler_from_quaternion (static xyz axes), in [-pi, pi]."""
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


# ------------------------------------------------------------------ the robot adapter's calls
@dataclass
class Call:
    """One query as free_fleet made it: what, how long until its replies were read, what they said."""

    key: str
    started: float  # time.monotonic()
    elapsed: float
    replies: list[Any] = field(default_factory=list)


class FreeFleetRobot:
    """One robot of free_fleet's ``Nav2RobotAdapter`` (navigation_stack: 2), without RMF around it."""

    def __init__(
        self,
        session: zenoh.Session,
        name: str,
        *,
        map_frame: str = "map",
        robot_frame: str = "base_footprint",
        service_call_timeout_sec: float | None = None,
        init_timeout_sec: float = 10.0,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.session = session
        self.name = name
        self.map_frame = map_frame
        self.robot_frame = robot_frame
        self.timeout = service_call_timeout_sec
        self.init_timeout_sec = init_timeout_sec
        self.clock = clock
        self.tf = TfBuffer()
        self.battery_soc = 1.0  # free_fleet: "Only use full battery if sim is indicated"
        self.goal_id: list[int] | None = None
        self.last_feedback: tuple[FeedbackMessage, int] | None = None  # ExecutionFeedback(feedback, time_sec)
        self.feedback_count = 0
        self.feedback_times: list[float] = []  # time.monotonic() of each feedback sample
        self.tf_samples = 0
        self.last_lookup_error = ""
        self.errors: list[str] = []
        self.calls: list[Call] = []
        self._subscribers = [
            session.declare_subscriber(namespacify("tf", name), self._on_tf),
            session.declare_subscriber(namespacify("battery_state", name), self._on_battery),
            session.declare_subscriber(namespacify("navigate_to_pose/_action/feedback", name), self._on_feedback),
        ]

    # -------------------------------------------------------------- subscriptions
    def _on_tf(self, sample: zenoh.Sample) -> None:
        try:
            message = TFMessage.deserialize(sample.payload.to_bytes())
        except Exception as exc:  # free_fleet: logged at debug, the sample dropped
            self.errors.append(f"tf: {type(exc).__name__}: {exc}")
            return
        self.tf_samples += 1
        for t in message.transforms:
            stamp = t.header.stamp.sec + t.header.stamp.nanosec * 1e-9
            v, q = t.transform.translation, t.transform.rotation
            stored = self.tf.set_transform(
                namespacify(t.header.frame_id, self.name),
                namespacify(t.child_frame_id, self.name),
                stamp,
                (v.x, v.y, v.z),
                (q.x, q.y, q.z, q.w),
            )
            if not stored:
                self.errors.append(f"tf: {t.header.frame_id} -> {t.child_frame_id} at {stamp} refused by the tf buffer")

    def _on_battery(self, sample: zenoh.Sample) -> None:
        try:
            self.battery_soc = float(BatteryState.deserialize(sample.payload.to_bytes()).percentage)
        except Exception as exc:  # free_fleet would raise in its callback
            self.errors.append(f"battery_state: {type(exc).__name__}: {exc}")

    def _on_feedback(self, sample: zenoh.Sample) -> None:
        self.feedback_times.append(time.monotonic())
        if self.goal_id is None:
            return
        try:
            feedback = FeedbackMessage.deserialize(sample.payload.to_bytes())
        except Exception as exc:
            self.errors.append(f"feedback: {type(exc).__name__}: {exc}")
            return
        self.feedback_count += 1
        self.last_feedback = (feedback, int(self.clock()))

    # -------------------------------------------------------------- the pose
    def get_pose(self) -> list[float] | None:
        """``get_pose``: [x, y, yaw] of robot_frame in map_frame, or None (free_fleet logs why)."""
        try:
            (x, y, _), rotation, _ = self.tf.lookup(namespacify(self.map_frame, self.name), namespacify(self.robot_frame, self.name))
        except (TfLookupError, KeyError) as exc:
            self.last_lookup_error = str(exc)
            return None
        return [x, y, yaw_from_quaternion(*rotation)]

    def initialize(self) -> tuple[list[float], float]:
        """The adapter's start: the pose tried every second until init_timeout_sec; the pose and the seconds it took."""
        started = time.monotonic()
        deadline = started + self.init_timeout_sec
        attempt = started
        while True:
            attempt += 1.0
            if attempt > deadline:
                raise RuntimeError(f"Timeout trying to initialize robot [{self.name}]")
            time.sleep(max(0.0, attempt - time.monotonic()))
            pose = self.get_pose()
            if pose is not None:
                return pose, time.monotonic() - started

    # -------------------------------------------------------------- queries
    def _get(self, name: str, payload: bytes) -> Call:
        key = namespacify(f"navigate_to_pose/_action/{name}", self.name)
        started = time.monotonic()
        replies = list(self.session.get(key, payload=payload, timeout=self.timeout))
        call = Call(key, started, time.monotonic() - started, replies)
        self.calls.append(call)
        return call

    def navigate(self, x: float, y: float, yaw: float, z: float = 0.0) -> tuple[bool | None, Call]:
        """``navigate`` + ``_handle_navigate_to_pose``: accepted (True), rejected (False), or no readable reply (None)."""
        self.stop()
        now = self.clock()
        qx, qy, qz, qw = quaternion_from_yaw(yaw)
        goal_id = [random.randint(0, 254) for _ in range(16)]  # np.random.randint(0, 255, size=16)
        request = SendGoalRequest(
            goal_id=goal_id,
            pose=PoseStamped(
                header=Header(stamp=Time(sec=int(now), nanosec=int((now % 1) * 1e9)), frame_id=self.map_frame),
                pose=Pose(position=Point(x=x, y=y, z=z), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw)),
            ),
            behavior_tree="",
        )
        call = self._get("send_goal", request.serialize())
        for reply in call.replies:
            try:
                response = SendGoalResponse.deserialize(reply.ok.payload.to_bytes())
            except Exception as exc:
                self.errors.append(f"send_goal: {self._why(reply, exc)}")
                continue
            if response.accepted:
                self.goal_id = goal_id
                self.last_feedback = None
                return True, call
            return False, call
        return None, call

    def is_navigation_done(self) -> tuple[bool | None, GoalStatus | None]:
        """``_is_navigation_done``: (done, the status read); (None, None) when get_result had no readable reply."""
        if self.goal_id is None:
            return True, None
        if self.last_feedback is not None:
            feedback, time_sec = self.last_feedback
            if time_sec + feedback.estimated_time_remaining.sec > int(self.clock()):
                return False, None  # not due yet: free_fleet does not ask
        call = self._get("get_result", GetResultRequest(goal_id=self.goal_id).serialize())
        for reply in call.replies:
            try:
                status = GetResultResponse.deserialize(reply.ok.payload.to_bytes()).status
            except Exception as exc:
                self.errors.append(f"get_result: {self._why(reply, exc)}")
                continue
            try:
                known = GoalStatus(status)
            except ValueError:
                return False, None  # free_fleet: an issue ticket and a replan
            if known in (GoalStatus.EXECUTING, GoalStatus.ACCEPTED, GoalStatus.CANCELING):
                return False, known
            if known in (GoalStatus.SUCCEEDED, GoalStatus.CANCELED):
                return True, known
            return False, known  # ABORTED, UNKNOWN: an issue ticket and a replan
        return None, None

    def stop(self) -> list[int]:
        """``_request_stop``: cancel-all when a goal is held; the return codes of the replies."""
        if self.goal_id is None:
            return []
        codes = self.cancel_all()
        self.goal_id = None
        return codes

    def cancel_all(self) -> list[int]:
        """``_handle_stop_navigation``: cancel_goal with a zero goal id and stamp; each reply's return_code."""
        call = self._get("cancel_goal", cancel_all_request().serialize())
        codes = []
        for reply in call.replies:
            try:  # free_fleet reads reply.ok unguarded here
                codes.append(int(CancelGoalResponse.deserialize(reply.ok.payload.to_bytes()).return_code))
            except Exception as exc:
                self.errors.append(f"cancel_goal: {self._why(reply, exc)}")
        return codes

    @staticmethod
    def _why(reply: Any, exc: Exception) -> str:
        if reply.err is not None:
            return f"error reply {reply.err.payload.to_bytes()!r}"
        return f"{type(exc).__name__}: {exc}"

    def close(self) -> None:
        for subscriber in self._subscribers:
            subscriber.undeclare()


_prepare_types()

__all__ = [
    "UUID",
    "BatteryState",
    "CancelGoalRequest",
    "CancelGoalResponse",
    "Duration",
    "FeedbackMessage",
    "FreeFleetRobot",
    "GetResultRequest",
    "GetResultResponse",
    "GoalInfo",
    "GoalStatus",
    "Header",
    "Point",
    "Pose",
    "PoseStamped",
    "Quaternion",
    "SendGoalRequest",
    "SendGoalResponse",
    "TFMessage",
    "TfBuffer",
    "TfLookupError",
    "Time",
    "Transform",
    "TransformStamped",
    "Vector3",
    "cancel_all_request",
    "namespacify",
]
