"""The view's names and its protocol's words, in one place: topics, services, frames, schemas of what clients send.

One robot's view uses the bare names (``/cmd_vel``, ``set_estop``, ``odom``); a fleet's robot ``r3`` has them
under ``/r3`` and its frames under ``r3/``, as ``ros2 --fleet`` names them. Every part builds and parses names here.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from enum import Enum, IntEnum
from typing import Any

from blackmetal.schemas import Sources

#: The command source the view's clients drive as (``<prefix>/cmd_vel/foxglove``).
COMMAND_SOURCE = Sources.FOXGLOVE
#: The one message encoding clients may publish and call services in.
CLIENT_ENCODING = "json"


class Control(Enum):
    CMD_VEL = "/cmd_vel"
    ESTOP = "/estop"


#: The schema names a client may advertise each control topic with (ROS 2 and ROS 1 spellings).
CONTROL_SCHEMAS: dict[Control, tuple[str, ...]] = {
    Control.CMD_VEL: ("geometry_msgs/msg/Twist", "geometry_msgs/Twist"),
    Control.ESTOP: ("std_msgs/msg/Bool", "std_msgs/Bool"),
}


class NavTopic(Enum):
    """What the 3D panel's publish tools advertise (RViz's names): goals, a pose estimate, a clicked point."""

    GOAL_POSE = "/goal_pose"
    MOVE_BASE_GOAL = "/move_base_simple/goal"
    INITIAL_POSE = "/initialpose"
    CLICKED_POINT = "/clicked_point"


_POSE_STAMPED = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/PoseStamped")
#: The schema names a client may advertise each navigation topic with (ROS 2 and ROS 1 spellings; Foxglove says ROS 1's).
NAV_SCHEMAS: dict[NavTopic, tuple[str, ...]] = {
    NavTopic.GOAL_POSE: _POSE_STAMPED,
    NavTopic.MOVE_BASE_GOAL: _POSE_STAMPED,
    NavTopic.INITIAL_POSE: ("geometry_msgs/msg/PoseWithCovarianceStamped", "geometry_msgs/PoseWithCovarianceStamped"),
    NavTopic.CLICKED_POINT: ("geometry_msgs/msg/PointStamped", "geometry_msgs/PointStamped"),
}
#: The robot's own frames (its URDF's root and body): a pose in one of them is relative to where the robot is.
BODY_FRAMES = ("base_link", "base_footprint")


class Service(Enum):
    SET_ESTOP = "set_estop"
    RESET_ODOMETRY = "reset_odometry"
    #: Cancels the goal the navigation service drives to (a get on ``<prefix>/nav/cancel``): the goals' stop button.
    CANCEL_GOAL = "cancel_goal"


def robot_namespace(robot_id: str) -> str:
    return f"/{robot_id}"


def robot_frame(robot_id: str, frame: str) -> str:
    """A fleet's robot's frame, prefixed as ``ros2 --fleet`` (diff_drive_controller) prefixes it: ``r3/odom``, ``r3/base_link``."""
    return f"{robot_id}/{frame}"


def control_topic(namespace: str, control: Control) -> str:
    return f"{namespace}{control.value}"


def service_name(namespace: str, service: Service) -> str:
    return f"{namespace}/{service.value}" if namespace else service.value


def nav_topic(namespace: str, topic: NavTopic) -> str:
    return f"{namespace}{topic.value}"


def takes(namespace: str = "") -> str:
    return " and ".join(f"{control_topic(namespace, c)} ({CONTROL_SCHEMAS[c][0]})" for c in Control) + ", JSON-encoded"


def nav_takes(namespace: str = "") -> str:
    """The 3D panel's topics, said once: where its publish tools' goals and pose estimates go."""
    goals = " and ".join(nav_topic(namespace, t) for t in (NavTopic.GOAL_POSE, NavTopic.MOVE_BASE_GOAL))
    return (
        f"{goals} (geometry_msgs/msg/PoseStamped: a goal, to nav/goal), {nav_topic(namespace, NavTopic.INITIAL_POSE)} "
        f"(PoseWithCovarianceStamped: to nav/set_pose), {nav_topic(namespace, NavTopic.CLICKED_POINT)} (shown in the log)"
    )


def robot_of(name: str, robot_ids: Collection[str]) -> str | None:
    """The robot a fleet topic or service name belongs to (``/r3/cmd_vel`` -> ``r3``), None when it names none of ``robot_ids``."""
    head, slash, rest = name.removeprefix("/").partition("/")
    return head if name.startswith("/") and slash and rest and head in robot_ids else None


def _object(properties: dict[str, Any], required: list[str] | None = None) -> dict[str, Any]:
    return {"type": "object", "properties": properties, "required": required or [], "additionalProperties": False}


_NUMBER = {"type": "number"}
_QUATERNION_SCHEMA = _object({name: _NUMBER for name in ("x", "y", "z", "w")})
_POSE_SCHEMA = _object({**{name: _NUMBER for name in ("stamp", "x", "y", "yaw", "v", "w")}, "orientation": _QUATERNION_SCHEMA})


@dataclass(frozen=True, slots=True)
class ServiceSpec:
    """A service as the protocol advertises it: its type, and the JSON Schemas (titled with their names) of request and response."""

    type: str
    request: dict[str, Any]
    response: dict[str, Any]


def _spec(ros_type: str, request: dict[str, Any], response: dict[str, Any], required: list[str] | None = None) -> ServiceSpec:
    return ServiceSpec(
        ros_type, {"title": f"{ros_type}_Request", **_object(request, required)}, {"title": f"{ros_type}_Response", **_object(response)}
    )


_RESULT = {"success": {"type": "boolean"}, "message": {"type": "string"}}
SERVICE_SPECS: dict[Service, ServiceSpec] = {
    Service.SET_ESTOP: _spec("std_srvs/srv/SetBool", {"data": {"type": "boolean"}}, _RESULT, ["data"]),
    Service.RESET_ODOMETRY: _spec(
        "blackmetal/srv/ResetOdometry", {"x": _NUMBER, "y": _NUMBER, "yaw": _NUMBER}, {**_RESULT, "pose": _POSE_SCHEMA}
    ),
    Service.CANCEL_GOAL: _spec("std_srvs/srv/Trigger", {}, _RESULT),
}


class StatusLevel(IntEnum):
    INFO = 0
    WARNING = 1
    ERROR = 2


class ServerRefusal(Enum):
    """What the WebSocket server itself sent a client when it refused something (the view saw it go out)."""

    STATUS = "status"
    SERVICE_CALL_FAILURE = "serviceCallFailure"


#: The fleet's own topics (``/fleet/summary``, ``/fleet/log``): a robot may not have this id in the fleet view.
FLEET_NAMESPACE = "/fleet"
