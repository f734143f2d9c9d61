"""Messages of the navigation service (``<prefix>/nav/...``): goals, moves, cancels, feedback, results, the map frame.

Goals come from any client (a web page, a script, the ROS 2 and Open-RMF adapters), so their payloads forbid unknown
fields: ``{"x": 1, "Y": 2}`` is an error, not a goal to (1, 0). Angles are radians, distances metres, times seconds.
"""

from __future__ import annotations

import math
from enum import StrEnum
from typing import Annotated

import msgspec

from .messages import Finite

#: A goal id: 32 lower-case hex digits (a UUID's 16 bytes, as ROS 2 action goal ids are). The service makes one when
#: the client gives none; the ROS 2 and Open-RMF adapters pass their UUID so that both sides name the goal alike.
GoalId = Annotated[str, msgspec.Meta(pattern="^[0-9a-f]{32}$", description="32 lower-case hex digits (a UUID)")]
#: The name of a frame: ``map`` (the site map, the default) or ``odom`` (the robot's odometry frame).
FrameName = Annotated[str, msgspec.Meta(min_length=1, max_length=64)]


class GoalState(StrEnum):
    """Where a goal is in its life (ROS 2's action states, without CANCELING: a cancel here takes effect at once)."""

    ACCEPTED = "accepted"
    EXECUTING = "executing"
    SUCCEEDED = "succeeded"
    CANCELED = "canceled"
    ABORTED = "aborted"

    @property
    def done(self) -> bool:
        return self in (GoalState.SUCCEEDED, GoalState.CANCELED, GoalState.ABORTED)


def _require_finite(owner: str, **values: float | None) -> None:
    for name, value in values.items():
        if value is not None and not math.isfinite(value):
            raise ValueError(f"{owner}.{name} must be a finite number, got {value!r}")


class NavGoal(msgspec.Struct, forbid_unknown_fields=True):
    """Payload of a get on ``<prefix>/nav/goal``: go to (x, y), facing ``yaw`` on arrival (None: any heading).

    ``frame`` is ``map`` (the site map, placed over the robot's odometry by its ``map_pose``) or ``odom``. A new goal
    preempts the one before it, which ends ``canceled``.
    """

    x: Finite
    y: Finite
    yaw: Finite | None = None
    frame: FrameName = "map"
    goal_id: GoalId | None = None

    def __post_init__(self) -> None:
        _require_finite("goal", x=self.x, y=self.y, yaw=self.yaw)


class NavMove(msgspec.Struct, forbid_unknown_fields=True):
    """Payload of a get on ``<prefix>/nav/move``: drive ``distance`` metres straight (negative: backwards), or turn
    ``angle`` radians on the spot (positive: left); one of the two, relative to where the robot is when it arrives."""

    distance: Finite = 0.0
    angle: Finite = 0.0
    goal_id: GoalId | None = None

    def __post_init__(self) -> None:
        _require_finite("move", distance=self.distance, angle=self.angle)
        if self.distance and self.angle:
            raise ValueError("move takes a distance or an angle, not both: send two moves one after the other")


class NavGoalReply(msgspec.Struct):
    """The answer to a goal or a move: accepted with its id, or rejected with a sentence that says why."""

    accepted: bool
    goal_id: str | None = None
    reason: str = ""


class NavCancel(msgspec.Struct, forbid_unknown_fields=True):
    """Payload of a get on ``<prefix>/nav/cancel``: the goal to cancel; none (or an empty payload): whatever runs."""

    goal_id: GoalId | None = None


class NavCancelReply(msgspec.Struct):
    """The answer to a cancel: the goals it ended (empty, with the reason, when there was nothing to cancel)."""

    canceled: list[str] = []
    reason: str = ""


class PlanarPose(msgspec.Struct):
    """A pose in a named frame: x, y (m), yaw (rad, in [-pi, pi])."""

    x: Finite
    y: Finite
    yaw: Finite
    frame: str = "map"


class NavFeedback(msgspec.Struct):
    """Published on ``<prefix>/nav/feedback`` while a goal runs (at least 5 Hz) and once when it ends.

    ``pose`` and ``goal`` are in the goal's frame; ``eta`` is the estimated time left at the controller's limits;
    ``reason`` says why a goal ended other than succeeded.
    """

    stamp: Finite
    goal_id: str
    state: GoalState
    pose: PlanarPose
    goal: PlanarPose
    distance_remaining: Finite
    eta: Finite
    elapsed: Finite
    recoveries: int = 0
    reason: str = ""


class NavResultQuery(msgspec.Struct, forbid_unknown_fields=True):
    """Payload of a get on ``<prefix>/nav/result``: the goal whose state to tell (none: the latest goal)."""

    goal_id: GoalId | None = None


class NavResult(msgspec.Struct):
    """A goal's state now: running, or how and why it ended. ``found`` is false for an id the service does not know."""

    found: bool
    goal_id: str | None = None
    state: GoalState | None = None
    reason: str = ""
    pose: PlanarPose | None = None
    goal: PlanarPose | None = None
    elapsed: float = 0.0


class MapPose(msgspec.Struct):
    """Where the robot's odometry frame sits on the site map (``map -> odom``), on ``<prefix>/nav/map_pose``.

    Published when it changes and answered to a get; ``by`` says what set it (settings, a set-pose, ``/initialpose``).
    """

    stamp: Finite
    x: Finite
    y: Finite
    yaw: Finite
    map: str = "map"
    by: str = "settings"


class SetPose(msgspec.Struct, forbid_unknown_fields=True):
    """Payload of a get on ``<prefix>/nav/set_pose``: the robot is at (x, y, yaw) on the map now (a localiser's answer,
    ROS's ``/initialpose``). The service moves ``map -> odom`` so that it is; the odometry is not touched."""

    x: Finite
    y: Finite
    yaw: Finite = 0.0
    frame: FrameName = "map"

    def __post_init__(self) -> None:
        _require_finite("set_pose", x=self.x, y=self.y, yaw=self.yaw)


#: The navigation messages, by the name used for its JSON Schema file.
NAV_MESSAGE_TYPES: dict[str, type[msgspec.Struct]] = {
    "NavGoal": NavGoal,
    "NavMove": NavMove,
    "NavGoalReply": NavGoalReply,
    "NavCancel": NavCancel,
    "NavCancelReply": NavCancelReply,
    "NavFeedback": NavFeedback,
    "NavResultQuery": NavResultQuery,
    "NavResult": NavResult,
    "MapPose": MapPose,
    "SetPose": SetPose,
}
