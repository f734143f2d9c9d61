"""The ROS 2 adapter's core: blackmetal payloads in, ROS messages out, and back. Pure and clock-injected.

A plain client of the robot's keys: ROS ``/cmd_vel`` and ``/estop`` become the gateway's own messages, so its limits,
timeout, arbitration and e-stop apply to ROS as to any client; what cannot be decoded is reported on
``<prefix>/errors``, never forwarded (docs/ros2-adapter.md says what each topic carries).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from blackmetal.robot_model import WheelAngles
from blackmetal.runtime.diagnostics import Status
from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import ErrorReport, EStop, GatewayHealth, Keys, PayloadError, Pose, WheelImpulses, decode, encode

from . import action_cdr
from .action_types import BATTERY_STATE, NavLayout
from .calls import ASK_HEALTH, ServiceCalls, decoded
from .diagnostics import DIAGNOSTICS_PERIOD_S, AdapterStats, Diagnostics
from .messages import RosCodec
from .naming import CMD_VEL_STAMPED, ROBOT_DESCRIPTION, TF_STATIC
from .navigate import ACTION_SERVICES, FEEDBACK, RMF, RMF_TF, NavAction
from .options import Ros2Options, Ros2Output
from .ros_types import BOOL, STRING, Transform

#: The gateway's command timeout (s) until its health has said what it is: how old a TwistStamped may be.
DEFAULT_CMD_TIMEOUT = 0.5

#: The ROS topics fed by a stream of the robot: published, and their streams followed, only while someone subscribes.
WATCHED_TOPICS = ("odom", "tf", "joint_states", "diagnostics")
#: The action's feedback (the node's, free_fleet's): encoded only while someone subscribes (the status always: it is
#: transient local, a late subscriber gets the last one).
WATCHED_FEEDBACK = (FEEDBACK, RMF + FEEDBACK)
#: The navigation's feedback, a robot stream every node follows: it keeps the action's goal states.
NAV_STREAM = "nav_feedback"


@dataclass(eq=False)
class Ros2Core:
    """Translates between the robot's keys and ROS topics and services (names relative to the node's namespace)."""

    options: Ros2Options
    keys: Keys
    output: Ros2Output
    codec: RosCodec
    wallclock: Callable[[], float] = time.time
    #: The watched topics someone subscribes to; None until the edge reports (then everything is published).
    watched: set[str] | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        o = self.options
        self.reporter = ErrorReporter("ros2", self.output.error, self.wallclock)
        self.joints = WheelAngles()
        self.cmd_vel_target = self.keys.cmd_vel_of(o.source)
        self.diagnostics = Diagnostics(self.keys, o.node, o.expected_poll_hz)
        self.stats = AdapterStats()
        self.calls = ServiceCalls(
            o, self.keys, self.output, self.codec, self.wallclock, self.reporter, self.stats, self._follow, self._reject
        )
        self.parameters = self.calls.parameters
        battery = self._battery if o.rmf_name and o.rmf_battery is not None else None
        self.nav = NavAction(
            self.keys, self.output, self.reporter, self.wallclock, NavLayout(o.nav_layout), o.frames.odom, bool(o.rmf_name), battery
        )
        self.nav.wants, self.nav.reject = self._wants, self._reject
        self._following: frozenset[str] | None = None
        self._next_diagnostics = -math.inf
        self._model_published = False

    def _reject(self, key: str, reason: str, snippet: str, now: float) -> None:
        self.stats.bad_inputs.add(now)
        self.reporter.report(key, reason, snippet, now=now)

    def on_pose(self, payload: bytes, now: float) -> None:
        pose = decoded(self.reporter, Pose, payload, self.keys.pose, now)
        if pose is None:
            return
        self.diagnostics.on_pose(now)
        o = self.options
        if self._wants("odom"):
            self.output.ros("odom", self.codec.odometry(pose, o.frames, o.pose_covariance, o.twist_covariance))
        tf = None
        if self._wants("tf"):
            tf = self._transforms(pose, o.frames.odom, o.frames.base)
            self.output.ros("tf", tf)
        if o.rmf_name:  # free_fleet looks map -> base_footprint up in <name>/tf, frames as Nav2 names them
            if tf is None or o.rmf_frames != o.frames:  # else (one robot): the same bytes, encoded once
                tf = self._transforms(pose, o.rmf_frames.odom, o.rmf_frames.base)
            self.output.ros(RMF_TF, tf)

    def _transforms(self, pose: Pose, odom: str, base: str) -> bytes:
        """``odom -> base`` of ``pose``, after ``map -> odom`` once the navigation service has placed it (same stamp)."""
        q = pose.orientation
        robot = Transform(odom, base, (pose.x, pose.y, 0.0), (q.x, q.y, q.z, q.w))
        placed = self.nav.map_transform(odom)
        return self.codec.transforms(pose.stamp, [robot] if placed is None else [placed, robot])

    def _battery(self) -> bytes:
        charge = self.options.rmf_battery or 0.0
        return self.codec.encode(
            BATTERY_STATE,
            **_battery_fields(self.codec, self.wallclock(), charge),
        )

    def on_service_request(self, service: str, call: int, cdr: bytes, request_attachment: bytes | None, now: float) -> None:
        """A call to one of the node's services, or to the action's (the node's, or free_fleet's with ``rmf/``)."""
        if service.removeprefix(RMF) not in ACTION_SERVICES:
            return self.calls.on_service_request(service, call, cdr, request_attachment, now)
        reply_to = self.calls.reply_to(service, call, request_attachment, now)
        if reply_to is not False:
            self.nav.on_request(service, call, cdr, reply_to, now)

    def on_goal_pose(self, cdr: bytes, now: float) -> None:
        try:
            self.nav.on_goal_pose(action_cdr.pose_stamped(cdr), now)
        except PayloadError as exc:
            self._reject(self.options.data_keys.get("goal_pose", "goal_pose"), str(exc), exc.excerpt, now)

    def on_initial_pose(self, cdr: bytes, now: float) -> None:
        try:
            self.nav.on_initial_pose(action_cdr.pose_with_covariance_stamped(cdr), now)
        except PayloadError as exc:
            self._reject(self.options.data_keys.get("initialpose", "initialpose"), str(exc), exc.excerpt, now)

    def on_impulses(self, payload: bytes, now: float) -> None:
        sample = decoded(self.reporter, WheelImpulses, payload, self.keys.impulses, now)
        if sample is None:
            return
        self.joints.feed(sample, self.options.encoders, self.options.wheel_radius)
        if self._wants("joint_states"):
            cdr = self.codec.joint_state(sample.stamp, list(self.options.joint_names), self.joints.positions, self.joints.velocities)
            self.output.ros("joint_states", cdr)
        robot = self.options.robot
        if robot is not None and robot.wheel_tf and self._wants("tf"):
            wheels = [wheel.transform(angle) for wheel, angle in zip(robot.wheels, self.joints.positions, strict=True)]
            self.output.ros("tf", self.codec.transforms(sample.stamp, wheels))

    def on_health(self, payload: bytes, now: float) -> None:
        """The gateway's health (published, or the answer to our ``get``): diagnostics, and e-stop confirmations."""
        health = decoded(self.reporter, GatewayHealth, payload, self.keys.health, now)
        if health is None:
            return
        self.diagnostics.on_health(health, now)
        self.calls.on_health(health, now)

    def on_error_report(self, payload: bytes, now: float) -> None:
        """A report on ``<prefix>/errors`` (ours included): the odometry's count as rejected samples."""
        try:
            report = decode(ErrorReport, payload)
        except PayloadError:
            return  # not ours to judge: whoever sent it reports nothing here
        self.diagnostics.on_error_report(report, now)

    def on_alive(self, who: str, alive: bool, now: float) -> None:
        """The gateway's, the odometry's or the navigation's liveliness token appeared (True) or went away (False)."""
        if who == "nav":
            return self.nav.on_alive(alive, now)
        if who == "gateway" and alive and self.diagnostics.gateway_alive is False:
            self.calls.ask_params()  # the gateway came back: its table may differ (another settings file, a restart)
        self.diagnostics.on_alive(who, alive)

    def start(self) -> None:
        """Once, when the node starts serving: ask for the gateway's parameters; from now on follow only what is watched."""
        self.calls.ask_params()
        self.nav.start()
        if self.watched is None:
            self.watched = set()
        self._follow()

    def _wants(self, topic: str) -> bool:
        """Someone watches ``topic`` (all of them until the edge reports); /tf only if the node publishes it."""
        return (self.watched is None or topic in self.watched) and (topic != "tf" or self.options.publish_tf)

    def _follow(self) -> None:
        """Follow the robot's streams the watched topics need (the health also while a set_estop waits for it), and
        the navigation's feedback."""
        if self.watched is None:
            return  # not started: the edge follows everything it declared
        robot = self.options.robot
        out = {NAV_STREAM}  # the action's goal states: always (nothing flows while no goal runs)
        if any(map(self._wants, ("odom", "tf", "diagnostics"))) or self.options.rmf_name:
            out.add("pose")
        if self._wants("joint_states") or (robot is not None and robot.wheel_tf and self._wants("tf")):
            out.add("impulses")
        if self._wants("diagnostics"):
            out.update(("errors", "health"))
        if self.calls.waits_for_health:
            out.add("health")
        if (needs := frozenset(out)) != self._following:
            self._following = needs
            self.output.follow(needs)

    def on_matched(self, topic: str, matched: bool, now: float) -> None:
        """Someone subscribes to ``topic`` now, or nobody does any more: publish it only while someone does."""
        if self.watched is None:
            self.watched = set()
        if matched:
            self.watched.add(topic)
        else:
            self.watched.discard(topic)
        self._follow()
        if matched and topic == "diagnostics":
            self._next_diagnostics = min(self._next_diagnostics, now)  # a new watcher gets the statuses at once

    def on_cmd_vel(self, cdr: bytes, now: float, stamped: bool = False) -> None:
        self.take_cmd_vel(cdr, now, stamped, report=True)

    def take_cmd_vel(self, cdr: bytes, now: float, stamped: bool = False, report: bool = False) -> bool:
        """Forward a ``/cmd_vel`` sample unless stale: the robot must not act on a command its publisher gave up on.

        Without ``report`` a refusal changes nothing, so the direct take on Zenoh's thread (which must not publish an
        error report) leaves the sample to :meth:`on_cmd_vel` on the loop, which refuses it again and reports why.
        """
        key = self.options.data_keys.get(CMD_VEL_STAMPED if stamped else "cmd_vel", "cmd_vel")
        try:
            twist, stamp = self.codec.twist_stamped(cdr) if stamped else (self.codec.twist(cdr), 0.0)
        except PayloadError as exc:
            if report:
                self._reject(key, str(exc), exc.excerpt, now)
            return False
        # the gateway's command timeout: from its parameters (published on each change), else its last health
        param, health = self.parameters.table.get("cmd_timeout"), self.diagnostics.health
        if param is not None and isinstance(param.value, (int, float)) and not isinstance(param.value, bool):
            timeout = float(param.value)
        else:
            timeout = DEFAULT_CMD_TIMEOUT if health is None else health.cmd_timeout
        age = self.wallclock() - stamp if stamp else 0.0
        if timeout > 0 and age > timeout:
            if report:
                reason = (
                    f"TwistStamped on /cmd_vel is {age:.3f} s old (header stamp {stamp:.3f}), older than the gateway's "
                    f"command timeout {timeout:g} s: refused (a zero stamp means now; check the publisher's clock and its delay)"
                )
                self._reject(key, reason, "", now)
            return False
        self.stats.commands += 1
        self.output.blackmetal(self.cmd_vel_target, encode(twist))
        return True

    def on_estop(self, cdr: bytes, now: float) -> None:
        try:
            estop = EStop(engaged=bool(self.codec.decode(cdr, BOOL).data))
        except PayloadError as exc:
            return self._reject(self.options.data_keys.get("estop", "estop"), str(exc), exc.excerpt, now)
        self.stats.estops += 1
        self.output.blackmetal(self.keys.estop_for(estop.engaged), encode(estop))

    def on_query_reply(self, tag: int, ok: bool, payload: bytes, now: float) -> None:
        """One reply to our query ``tag`` (``ok`` False: an error reply, ``payload`` its text)."""
        if tag < 0:
            self.nav.on_query_reply(tag, ok, payload, now)
        elif self.calls.queries.get(tag, ("", None))[0] != ASK_HEALTH:
            self.calls.on_query_reply(tag, ok, payload, now)
        elif ok:
            self.on_health(payload, now)

    def on_query_done(self, tag: int, now: float) -> None:
        """No more replies to ``tag`` (the action's queries are the negative tags)."""
        if tag < 0:
            self.nav.on_query_done(tag, now)
        else:
            self.calls.on_query_done(tag, now)

    def statuses(self, now: float) -> list[Status]:
        d = self.diagnostics
        return [d.robot_link(now), d.odometry(now), d.adapter(now, self.stats, self.options, len(self.calls.pending))]

    def tick(self, now: float) -> None:
        """Run what is due at ``now``: the robot model (first tick), calls, diagnostics, error-report summaries."""
        robot = self.options.robot
        if robot is not None and not self._model_published:  # once: transient-local publishers keep it for late joiners
            self.output.ros(ROBOT_DESCRIPTION, self.codec.encode(STRING, data=robot.urdf))
            self.output.ros(TF_STATIC, self.codec.transforms(self.wallclock(), robot.fixed))
            self._model_published = True
        self.calls.tick(now)
        self.nav.tick(now)
        if now >= self._next_diagnostics:
            if self._wants("diagnostics"):  # nobody subscribes: nothing encoded
                self.output.ros("diagnostics", self.codec.diagnostics(self.wallclock(), self.statuses(now)))
            due = self._next_diagnostics + DIAGNOSTICS_PERIOD_S
            self._next_diagnostics = due if due > now else now + DIAGNOSTICS_PERIOD_S
        self.reporter.tick(now)

    def next_deadline(self) -> float:
        diagnostics = self._next_diagnostics if self._wants("diagnostics") else math.inf  # nobody watches: no timer
        deadline = min(diagnostics, self.reporter.next_deadline(), self.nav.next_deadline())
        if self.calls.pending:  # asked after every pose: the common case, no call pending, builds nothing
            deadline = min(deadline, self.calls.next_deadline())
        return deadline


def _battery_fields(codec: RosCodec, stamp: float, charge: float) -> dict[str, object]:
    """sensor_msgs/BatteryState with only ``percentage`` known (free_fleet reads nothing else): NaN where unmeasured."""
    import numpy as np

    nan = float("nan")
    return {
        "header": codec.header(stamp, ""),
        "voltage": nan,
        "temperature": nan,
        "current": nan,
        "charge": nan,
        "capacity": nan,
        "design_capacity": nan,
        "percentage": charge,
        "power_supply_status": 0,
        "power_supply_health": 0,
        "power_supply_technology": 0,
        "present": True,
        "cell_voltage": np.zeros(0, dtype=np.float32),
        "cell_temperature": np.zeros(0, dtype=np.float32),
        "location": "",
        "serial_number": "",
    }
