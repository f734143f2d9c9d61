"""The ``navigate_to_pose`` action's types: nav2_msgs' definitions per distro, rosidl's hidden services and topics of an
action, and their RIHS01 type hashes computed from those definitions.

An action is three services and two topics (rcl_action, ``<name>/_action/...``): ``send_goal``
(``NavigateToPose_SendGoal``), ``cancel_goal`` (``action_msgs/srv/CancelGoal``), ``get_result``
(``NavigateToPose_GetResult``), ``feedback`` (``NavigateToPose_FeedbackMessage``) and ``status``
(``action_msgs/msg/GoalStatusArray``, transient local). rosidl describes ``_SendGoal`` as the service of
``{UUID goal_id, _Goal goal}`` and ``{bool accepted, Time stamp}``, with its ``_Event`` as for any service; the same
construction gives the published Jazzy hashes of ``action_tutorials_interfaces/action/Fibonacci`` (its test holds them).
"""

from __future__ import annotations

import functools
from enum import StrEnum
from typing import Any

from .naming import TRANSIENT_LOCAL, Direction, Distro, RosService, RosTopic

PACKAGE = "nav2_msgs/action/NavigateToPose"
SEND_GOAL = f"{PACKAGE}_SendGoal"
GET_RESULT = f"{PACKAGE}_GetResult"
FEEDBACK_MESSAGE = f"{PACKAGE}_FeedbackMessage"
CANCEL_GOAL = "action_msgs/srv/CancelGoal"
GOAL_STATUS_ARRAY = "action_msgs/msg/GoalStatusArray"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_WITH_COVARIANCE_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
BATTERY_STATE = "sensor_msgs/msg/BatteryState"

#: The action's name, relative to the node's namespace, as Nav2's bt_navigator serves it.
ACTION_NAME = "navigate_to_pose"


class NavLayout(StrEnum):
    """NavigateToPose's layouts (navigation2's ``nav2_msgs/action/NavigateToPose.action`` on each distro's branch)."""

    HUMBLE = "humble"  # Result {std_msgs/Empty result}
    JAZZY = "jazzy"  # Result {uint16 error_code, string error_msg} (jazzy, kilted)
    ROLLING = "rolling"  # and Feedback + position_tracking_error, heading_tracking_error (lyrical, main)


def layout_of(distro: Distro) -> NavLayout:
    if distro is Distro.HUMBLE:
        return NavLayout.HUMBLE
    if distro in (Distro.JAZZY, Distro.KILTED):
        return NavLayout.JAZZY
    return NavLayout.ROLLING


GOAL = "geometry_msgs/msg/PoseStamped pose\nstring behavior_tree"
_FEEDBACK = (
    "geometry_msgs/msg/PoseStamped current_pose\nbuiltin_interfaces/msg/Duration navigation_time\n"
    "builtin_interfaces/msg/Duration estimated_time_remaining\nint16 number_of_recoveries\nfloat32 distance_remaining"
)
#: (Goal, Result, Feedback) of each layout; constants left out (rosidl does not hash them).
DEFINITIONS = {
    NavLayout.HUMBLE: (GOAL, "std_msgs/msg/Empty result", _FEEDBACK),
    NavLayout.JAZZY: (GOAL, "uint16 error_code\nstring error_msg", _FEEDBACK),
    NavLayout.ROLLING: (
        GOAL,
        "uint16 error_code\nstring error_msg",
        _FEEDBACK + "\nfloat32 position_tracking_error\nfloat32 heading_tracking_error",
    ),
}
#: action_msgs/srv/CancelGoal (rcl_interfaces, the same on humble, jazzy and rolling).
CANCEL_GOAL_DEFINITION = ("action_msgs/msg/GoalInfo goal_info", "int8 return_code\naction_msgs/msg/GoalInfo[] goals_canceling")

#: nav2_msgs' result codes (Jazzy+): UNKNOWN is what bt_navigator gives an abort it has no better code for.
ERROR_NONE, ERROR_UNKNOWN = 0, 9000


def _fix(name: str) -> str:
    """rosbags reads ``pkg/action/Name`` as ``pkg/action/msg/Name`` (and ``srv`` alike)."""
    return name.replace("/action/msg/", "/action/").replace("/srv/msg/", "/srv/")


def action_type_definitions(action: str, goal: str, result: str, feedback: str) -> dict[str, str]:
    """Every type rosidl generates for ``action``'s hidden services and topics, as ``.msg`` text by name."""
    out = {f"{action}_Goal": goal, f"{action}_Result": result, f"{action}_Feedback": feedback}
    out.update(
        service_type_definitions(
            f"{action}_SendGoal",
            f"unique_identifier_msgs/msg/UUID goal_id\n{action}_Goal goal",
            "bool accepted\nbuiltin_interfaces/msg/Time stamp",
        )
    )
    out.update(
        service_type_definitions(f"{action}_GetResult", "unique_identifier_msgs/msg/UUID goal_id", f"int8 status\n{action}_Result result")
    )
    out[f"{action}_FeedbackMessage"] = f"unique_identifier_msgs/msg/UUID goal_id\n{action}_Feedback feedback"
    return out


def service_type_definitions(service: str, request: str, response: str) -> dict[str, str]:
    """A service's four types as rosidl describes them: request, response, event, the service."""
    return {
        f"{service}_Request": request,
        f"{service}_Response": response,
        f"{service}_Event": f"service_msgs/msg/ServiceEventInfo info\n{service}_Request[<=1] request\n{service}_Response[<=1] response",
        service: f"{service}_Request request_message\n{service}_Response response_message\n{service}_Event event_message",
    }


def register(store: Any, definitions: dict[str, str]) -> None:
    """Add ``definitions`` to a rosbags store, their fields read as rosidl reads them."""
    from rosbags.typesys import get_types_from_msg
    from rosbags.typesys.base import Nodetype

    from .ros_types import _as_rosidl

    def fixed(desc: Any) -> Any:
        kind, rest = desc
        if kind == Nodetype.NAME:
            return (kind, _fix(rest))
        if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            return (kind, (fixed(rest[0]), rest[1]))
        return desc

    types: dict[str, Any] = {}
    for typename, text in definitions.items():
        for name, (consts, fields) in get_types_from_msg(text, typename).items():
            types[_fix(name)] = (consts, [(fname, fixed(_as_rosidl(desc))) for fname, desc in fields])
    store.register(types)


@functools.cache
def action_hashes(layout: NavLayout) -> dict[str, str]:
    """The RIHS01 hash of each type the action's entities name, for ``layout`` (Humble's are never used: it has none)."""
    from .ros_types import type_store

    store = type_store()
    register(
        store, {**action_type_definitions(PACKAGE, *DEFINITIONS[layout]), **service_type_definitions(CANCEL_GOAL, *CANCEL_GOAL_DEFINITION)}
    )
    names = (SEND_GOAL, GET_RESULT, FEEDBACK_MESSAGE, CANCEL_GOAL, GOAL_STATUS_ARRAY, POSE_STAMPED, POSE_WITH_COVARIANCE_STAMPED)
    return {name: str(store.hash_rihs01(name)) for name in names}


#: Labels of the node's navigation topics in its data keys.
ACTION_FEEDBACK, ACTION_STATUS, GOAL_POSE, INITIAL_POSE = (
    "navigate_to_pose/_action/feedback",
    "navigate_to_pose/_action/status",
    "goal_pose",
    "initialpose",
)


def nav_topics() -> list[RosTopic]:
    """The action's two topics (status: rcl_action's keep-last 1, reliable, transient local) and RViz's two pose tools;
    numbered after the node's services, so that the entities before them keep their ids."""
    return [
        RosTopic(ACTION_FEEDBACK, FEEDBACK_MESSAGE, Direction.PUBLISH),
        RosTopic(ACTION_STATUS, GOAL_STATUS_ARRAY, Direction.PUBLISH, qos=TRANSIENT_LOCAL),
        RosTopic(GOAL_POSE, POSE_STAMPED, Direction.SUBSCRIBE),
        RosTopic(INITIAL_POSE, POSE_WITH_COVARIANCE_STAMPED, Direction.SUBSCRIBE),
    ]


def nav_services() -> list[RosService]:
    """The action's three services, in the order rcl_action creates them (rmw_qos_profile_services_default)."""
    return [
        RosService(f"{ACTION_NAME}/_action/send_goal", SEND_GOAL),
        RosService(f"{ACTION_NAME}/_action/cancel_goal", CANCEL_GOAL),
        RosService(f"{ACTION_NAME}/_action/get_result", GET_RESULT),
    ]
