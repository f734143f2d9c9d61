"""The navigate_to_pose action's messages, ``/goal_pose`` and ``/initialpose`` as CDR, written and read by hand.

Plain CDR (XCDR1) as ROS 2 writes it: a 4-byte encapsulation header (``00 01 00 00``: little-endian), then each
primitive aligned to its size counted from after the header, strings as a uint32 length with the NUL then the bytes,
sequences as a uint32 count. Hand-written because the layouts differ by distro (nav2_msgs' Result and Feedback) and a
test holds each one to bytes computed by hand and to rosbags' own serializer. Reading takes either endianness and
refuses, in a sentence, anything that is not exactly one message or carries a non-finite number.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

from blackmetal.schemas import PayloadError

from .action_types import NavLayout
from .ros_types import excerpt

HEADER_LE = b"\x00\x01\x00\x00"
UUID_SIZE = 16
ZERO_UUID = bytes(UUID_SIZE)


class Writer:
    """Little-endian CDR, aligned from after the encapsulation header."""

    def __init__(self) -> None:
        self.body = bytearray()

    def _put(self, fmt: str, size: int, *values: object) -> None:
        self.body += b"\x00" * (-len(self.body) % size)
        self.body += struct.pack("<" + fmt, *values)

    def u8(self, v: int) -> None:
        self.body.append(v & 0xFF)

    def i8(self, v: int) -> None:
        self._put("b", 1, v)

    def i16(self, v: int) -> None:
        self._put("h", 2, v)

    def u16(self, v: int) -> None:
        self._put("H", 2, v)

    def i32(self, v: int) -> None:
        self._put("i", 4, v)

    def u32(self, v: int) -> None:
        self._put("I", 4, v)

    def f32(self, v: float) -> None:
        self._put("f", 4, v)

    def f64(self, *vs: float) -> None:
        for v in vs:
            self._put("d", 8, v)

    def string(self, text: str) -> None:
        data = text.encode() + b"\x00"
        self.u32(len(data))
        self.body += data

    def raw(self, data: bytes) -> None:
        self.body += data

    def time(self, sec: int, nanosec: int) -> None:
        self.i32(sec)
        self.u32(nanosec)

    def bytes(self) -> bytes:
        return HEADER_LE + bytes(self.body)


class Reader:
    """Reads one CDR message of ``kind`` (named in every refusal); :meth:`end` checks nothing is left over."""

    def __init__(self, payload: bytes, kind: str) -> None:
        self.payload, self.kind = payload, kind
        if len(payload) < 4 or payload[:2] not in (b"\x00\x01", b"\x00\x00"):
            self.fail(f"{len(payload)} bytes that do not start with a plain CDR encapsulation header (00 01 00 00)")
        self.endian = "<" if payload[1] == 1 else ">"
        self.offset = 4

    def fail(self, why: str) -> None:
        raise PayloadError(self.kind, why, excerpt(self.payload))

    def _get(self, fmt: str, size: int) -> tuple[object, ...]:
        self.offset += -(self.offset - 4) % size
        end = self.offset + struct.calcsize(fmt)
        if end > len(self.payload):
            self.fail(f"{len(self.payload)} bytes: too short for a CDR {self.kind}")
        values = struct.unpack_from(self.endian + fmt, self.payload, self.offset)
        self.offset = end
        return values

    def u8(self) -> int:
        return int(self._get("B", 1)[0])  # type: ignore[call-overload]

    def i8(self) -> int:
        return int(self._get("b", 1)[0])  # type: ignore[call-overload]

    def u32(self) -> int:
        return int(self._get("I", 4)[0])  # type: ignore[call-overload]

    def i32(self) -> int:
        return int(self._get("i", 4)[0])  # type: ignore[call-overload]

    def f64(self, name: str, count: int = 1) -> tuple[float, ...]:
        values = tuple(float(v) for v in self._get(f"{count}d", 8))  # type: ignore[arg-type]
        if not all(map(math.isfinite, values)):
            self.fail(f"{name} must be finite numbers, got {list(values)}")
        return values

    def raw(self, size: int) -> bytes:
        if self.offset + size > len(self.payload):
            self.fail(f"{len(self.payload)} bytes: too short for a CDR {self.kind}")
        self.offset += size
        return self.payload[self.offset - size : self.offset]

    def string(self, name: str) -> str:
        length = self.u32()
        data = self.raw(length)
        if length == 0 or data[-1] != 0:
            self.fail(f"{name} is not a CDR string (length {length} without its closing NUL)")
        try:
            return data[:-1].decode()
        except UnicodeDecodeError:
            self.fail(f"{name} is not UTF-8")
        raise AssertionError  # pragma: no cover

    def time(self) -> tuple[int, int]:
        return self.i32(), self.u32()

    def end(self) -> None:
        """Nothing but up to 3 bytes of padding may follow (some writers round the message up to 4 bytes)."""
        rest = len(self.payload) - self.offset
        if rest > 3:
            self.fail(f"{rest} bytes left over after the {self.kind}: not one message of this type (another distro's layout?)")


@dataclass(frozen=True, slots=True)
class StampedPose:
    """A PoseStamped's header and planar pose: ``yaw`` None when the orientation is all zeros (no heading asked)."""

    sec: int
    nanosec: int
    frame: str
    x: float
    y: float
    yaw: float | None


def yaw_of(qx: float, qy: float, qz: float, qw: float) -> float | None:
    if qx == qy == qz == qw == 0.0:
        return None
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def _pose_stamped(r: Reader, what: str) -> StampedPose:
    sec, nanosec = r.time()
    frame = r.string(f"{what}.header.frame_id")
    x, y, _ = r.f64(f"{what}.pose.position", 3)
    q = r.f64(f"{what}.pose.orientation", 4)
    return StampedPose(sec, nanosec, frame, x, y, yaw_of(*q))


def pose_stamped(payload: bytes) -> StampedPose:
    """geometry_msgs/PoseStamped (RViz's 2D Goal Pose)."""
    r = Reader(payload, "PoseStamped")
    pose = _pose_stamped(r, "pose")
    r.end()
    return pose


def pose_with_covariance_stamped(payload: bytes) -> StampedPose:
    """geometry_msgs/PoseWithCovarianceStamped (RViz's 2D Pose Estimate); the covariance is read and not kept."""
    r = Reader(payload, "PoseWithCovarianceStamped")
    pose = _pose_stamped(r, "pose")
    r.f64("pose.covariance", 36)
    r.end()
    return pose


def send_goal_request(payload: bytes) -> tuple[bytes, StampedPose, str]:
    """NavigateToPose_SendGoal_Request: (goal id, pose, behavior_tree); the Goal is the same on every distro."""
    r = Reader(payload, "NavigateToPose_SendGoal_Request")
    uuid = r.raw(UUID_SIZE)
    pose = _pose_stamped(r, "goal.pose")
    tree = r.string("goal.behavior_tree")
    r.end()
    return uuid, pose, tree


def get_result_request(payload: bytes) -> bytes:
    r = Reader(payload, "NavigateToPose_GetResult_Request")
    uuid = r.raw(UUID_SIZE)
    r.end()
    return uuid


def cancel_goal_request(payload: bytes) -> tuple[bytes, int, int]:
    """action_msgs/CancelGoal_Request: (goal id, stamp sec, nanosec); all zero: cancel every goal."""
    r = Reader(payload, "CancelGoal_Request")
    uuid = r.raw(UUID_SIZE)
    sec, nanosec = r.time()
    r.end()
    return uuid, sec, nanosec


def send_goal_response(accepted: bool, sec: int, nanosec: int) -> bytes:
    w = Writer()
    w.u8(int(accepted))
    w.time(sec, nanosec)
    return w.bytes()


def get_result_response(layout: NavLayout, status: int, error_code: int = 0, error_msg: str = "") -> bytes:
    """NavigateToPose_GetResult_Response: Humble's Result is std_msgs/Empty (one placeholder byte)."""
    w = Writer()
    w.i8(status)
    if layout is NavLayout.HUMBLE:
        w.u8(0)
    else:
        w.u16(error_code)
        w.string(error_msg)
    return w.bytes()


#: A goal as action_msgs names it: (UUID, accept stamp sec, nanosec).
GoalInfo = tuple[bytes, int, int]


def cancel_goal_response(return_code: int, goals: Sequence[GoalInfo]) -> bytes:
    w = Writer()
    w.i8(return_code)
    w.u32(len(goals))
    for uuid, sec, nanosec in goals:
        w.raw(uuid)
        w.time(sec, nanosec)
    return w.bytes()


def status_array(goals: Sequence[tuple[GoalInfo, int]]) -> bytes:
    """action_msgs/GoalStatusArray of ((UUID, sec, nanosec), status) pairs."""
    w = Writer()
    w.u32(len(goals))
    for (uuid, sec, nanosec), status in goals:
        w.raw(uuid)
        w.time(sec, nanosec)
        w.i8(status)
    return w.bytes()


def duration(seconds: float) -> tuple[int, int]:
    """builtin_interfaces/Duration of ``seconds`` (>= 0; sec floored, nanosec the rest)."""
    seconds = max(0.0, seconds) if math.isfinite(seconds) else 0.0
    sec = int(seconds)
    return sec, min(round((seconds - sec) * 1e9), 999_999_999)


@dataclass(frozen=True, slots=True)
class Feedback:
    """NavigateToPose_Feedback's values."""

    sec: int
    nanosec: int
    frame: str
    x: float
    y: float
    yaw: float
    navigation_time: float
    estimated_time_remaining: float
    number_of_recoveries: int
    distance_remaining: float


def feedback_message(layout: NavLayout, uuid: bytes, f: Feedback) -> bytes:
    """NavigateToPose_FeedbackMessage; Lyrical's and Rolling's tracking errors are written 0 (no path is tracked)."""
    w = Writer()
    w.raw(uuid)
    w.time(f.sec, f.nanosec)
    w.string(f.frame)
    w.f64(f.x, f.y, 0.0, 0.0, 0.0, math.sin(f.yaw / 2), math.cos(f.yaw / 2))
    w.time(*duration(f.navigation_time))
    w.time(*duration(f.estimated_time_remaining))
    w.i16(max(-32768, min(32767, f.number_of_recoveries)))
    w.f32(f.distance_remaining)
    if layout is NavLayout.ROLLING:
        w.f32(0.0)
        w.f32(0.0)
    return w.bytes()
