"""The few messages written and read straight as little-endian CDR, where rosbags is too slow for the hot path.

Every fleet ``/odom`` is written here (7 us against rosbags' 18), every ROS command read here on Zenoh's thread
(2 us against 8). Anything else goes to rosbags, which says what is wrong; a test holds both paths equal.
"""

from __future__ import annotations

import struct
from typing import Any

from blackmetal.schemas import Pose, stamp_parts

from .ros_types import Frames

#: A command's six doubles in little-endian CDR; and a TwistStamped's header stamp and frame_id length.
SIX_DOUBLES = struct.Struct("<6d")
_STAMP_AND_LENGTH = struct.Struct("<iII")
_CDR_LE = b"\x00\x01\x00\x00"
_STAMP = struct.Struct("<iI")
_SEVEN_DOUBLES = struct.Struct("<7d")
_COVARIANCE = struct.Struct("<36d")
#: A little-endian geometry_msgs/Twist: the 4-byte header and six doubles.
TWIST_LE_SIZE = 52


def twist_le(payload: bytes) -> tuple[float, ...] | None:
    """The six doubles of a little-endian geometry_msgs/Twist (rmw_zenoh's own); None for anything else."""
    if len(payload) == TWIST_LE_SIZE and payload[:2] == b"\x00\x01":
        return SIX_DOUBLES.unpack_from(payload, 4)
    return None


def twist_stamped_le(payload: bytes) -> tuple[int, int, tuple[float, ...]] | None:
    """(sec, nanosec, the six doubles) of a little-endian TwistStamped; None for anything else (rosbags says why).

    After the 4-byte header: int32 sec, uint32 nanosec, uint32 length of frame_id with its NUL, its bytes, padding
    to 8 (counted from after the header), six doubles.
    """
    if len(payload) < 68 or payload[:2] != b"\x00\x01":
        return None
    sec, nanosec, length = _STAMP_AND_LENGTH.unpack_from(payload, 4)
    end = 16 + length
    start = 4 + (end - 4 + 7) // 8 * 8
    if length == 0 or len(payload) != start + 48 or payload[end - 1] != 0:
        return None
    try:
        payload[16 : end - 1].decode()
    except UnicodeDecodeError:
        return None
    return sec, nanosec, SIX_DOUBLES.unpack_from(payload, start)


def _cdr_string(text: str, offset: int) -> tuple[bytes, int]:
    """A CDR string at ``offset`` (counted after the encapsulation header): its padding to 4, length with the NUL, bytes."""
    data = text.encode() + b"\x00"
    pad = -offset % 4
    return b"\x00" * pad + struct.pack("<I", len(data)) + data, offset + pad + 4 + len(data)


def odometry_frames(frames: Frames) -> bytes:
    """nav_msgs/Odometry's bytes between the stamp and the first double: frame_id, child_frame_id, padding to 8."""
    header, offset = _cdr_string(frames.odom, 8)
    child, offset = _cdr_string(frames.base, offset)
    return header + child + b"\x00" * (-offset % 8)


def odometry(pose: Pose, frames_bytes: bytes, pose_covariance: Any, twist_covariance: Any) -> bytes:
    """nav_msgs/Odometry in little-endian CDR; ``frames_bytes`` is :func:`odometry_frames` of the node's frames."""
    sec, nanosec = stamp_parts(pose.stamp)
    q = pose.orientation
    return b"".join(
        (
            _CDR_LE,
            _STAMP.pack(sec, nanosec),
            frames_bytes,
            _SEVEN_DOUBLES.pack(pose.x, pose.y, 0.0, q.x, q.y, q.z, q.w),
            _COVARIANCE.pack(*pose_covariance),
            SIX_DOUBLES.pack(pose.v, 0.0, 0.0, 0.0, 0.0, pose.w),
            _COVARIANCE.pack(*twist_covariance),
        )
    )
