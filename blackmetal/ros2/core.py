"""The ROS 2 adapter's core: blackmetal payloads in, ROS messages out, and back. Pure and clock-injected.

It is a plain client of the robot's keys: poses become ``/odom`` and
``/tf``, impulses become ``/joint_states``, and ROS ``/cmd_vel`` and
``/estop`` become the JSON messages the gateway already takes (``/cmd_vel``
as the command source ``ros2``, or ``--source``), so the gateway's limits,
timeout, arbitration and emergency stop apply to ROS exactly as to any
other client. Whatever cannot be decoded is reported on ``<prefix>/errors``
with the reason and is never forwarded.

Parameters are the gateway's (:mod:`blackmetal.ros2.parameters`): the
node answers rclcpp's six parameter services from the gateway's table, sends
sets to the gateway and answers with its results, and publishes each change
on ``/parameter_events``.

Two services, and ``/diagnostics``, are built from two parts here:

* :class:`PendingCall` s: a ``set_estop`` puts the e-stop and asks the
  gateway's health every :data:`ESTOP_REPEAT_S` until the health shows the
  asked state; a ``reset_odometry`` asks the odometry to reset and waits for
  its answer. Each call is answered once: ``success=true`` when confirmed,
  ``success=false`` with the reason when refused or at its deadline.
* :class:`Diagnostics`: the latest health, pose, odometry reports and
  liveliness it was fed, turned into three ``DiagnosticStatus`` (robot
  link, odometry, adapter) every :data:`DIAGNOSTICS_PERIOD_S` by the
  thresholds below (the README lists them).

Every input comes with ``now`` (the receiver's monotonic time); what is due
later (diagnostics, e-stop repeats, call deadlines, summaries of
rate-limited error reports) goes out in :meth:`Ros2Core.tick`, at
:meth:`Ros2Core.next_deadline`. No I/O and no clock read here:
:mod:`blackmetal.ros2.host` runs it on a loop, and tests call it directly.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Protocol

from blackmetal.robot_model import Encoders
from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import (
    ErrorReport,
    EStop,
    GatewayHealth,
    GatewayParams,
    Keys,
    ParamsSetReply,
    PayloadError,
    Pose,
    Sources,
    WheelImpulses,
    decode,
    encode,
)

from .messages import RosCodec
from .naming import (
    PARAMETER_EVENTS,
    PARAMETER_SERVICES,
    RESET_ODOMETRY,
    ROBOT_DESCRIPTION,
    SET_ESTOP,
    TF_STATIC,
    attachment,
    parse_attachment,
)
from .parameters import NodeParameters
from .ros_types import SET_BOOL, TRIGGER, Diagnostic, Frames, Level, RosValue, Transform, excerpt

#: Joint positions are not integrated across a gap longer than this (s): a lost link is not motion.
MAX_JOINT_GAP_S = 0.5
#: The gateway's command timeout (s) until its health has said what it is: how old a TwistStamped may be.
DEFAULT_CMD_TIMEOUT = 0.5

# ---- services
#: A pending set_estop puts the e-stop again and asks the gateway's health this often (s), as ``blackmetal estop`` does.
ESTOP_REPEAT_S = 0.1
#: Calls waiting for their confirmation at once; one more is answered success=false at once.
MAX_PENDING_CALLS = 16
#: A reset is confirmed by the odometry answering a pose this close to the origin (m, rad).
RESET_TOLERANCE = 1e-9

# ---- diagnostics: the README's table
DIAGNOSTICS_PERIOD_S = 1.0
#: Counting windows for lost replies, rejected samples, bad ROS inputs and failed calls (s).
WINDOW_S = 10.0
#: Robot link: STALE after this long without a health report (the gateway reports every 1 s).
HEALTH_STALE_S = 3.0
#: Robot link: WARN / ERROR when the measured poll rate is below this fraction of the asked one.
POLL_WARN_RATIO = 0.9
POLL_ERROR_RATIO = 0.5
#: Robot link: WARN / ERROR when the last round trip is longer (ms); the gateway gives a request up after 500 ms.
RTT_WARN_MS = 100.0
RTT_ERROR_MS = 250.0
#: Robot link: ERROR when at least this fraction of the polls of the window lost their reply (any: WARN).
LOST_ERROR_FRACTION = 0.1
#: Odometry: WARN when the last pose is older than this (s), STALE beyond POSE_STALE_S.
POSE_LATE_S = 0.5
POSE_STALE_S = 2.0
#: Odometry: ERROR at this many rejected samples in the window (any: WARN); 25 in 10 s is 5 % at 50 Hz.
REJECTED_ERROR_COUNT = 25


class Ros2Output(Protocol):
    """Where the core's messages go: ROS topics, blackmetal keys, error reports, service answers and queries."""

    def ros(self, topic: str, cdr: bytes) -> None: ...
    def blackmetal(self, key: str, payload: bytes) -> None: ...
    def error(self, message: ErrorReport) -> None: ...
    def service_reply(self, call: int, cdr: bytes, attachment: bytes | None) -> None:
        """Answer the service call ``call`` (once) with the CDR response and, for rmw_zenoh, its attachment."""

    def service_refuse(self, call: int, reason: str) -> None:
        """Answer ``call`` with a Zenoh error reply: it carries no usable request id to answer with a response."""

    def query(self, key: str, payload: bytes | None, tag: int, timeout: float) -> None:
        """``get`` on ``key``; each reply comes back as ``on_query_reply(tag, ...)``, then ``on_query_done(tag)``."""

    def follow(self, streams: frozenset[str]) -> None:
        """Subscribe to exactly these of the robot's streams (``pose``, ``impulses``, ``errors``, ``health``), no others."""


@dataclass(frozen=True, slots=True)
class Wheel:
    """A wheel's transform from ``/joint_states``: ``parent`` -> ``child`` at ``y`` (m), turned about +y by its angle."""

    parent: str
    child: str
    y: float

    def transform(self, angle: float) -> Transform:
        return Transform(self.parent, self.child, (0.0, self.y, 0.0), (0.0, math.sin(angle / 2), 0.0, math.cos(angle / 2)))


@dataclass(frozen=True, slots=True)
class RobotModel:
    """What robot_state_publisher would publish for the URDF: the text, its fixed joints, its two wheels (left, right)."""

    urdf: str
    fixed: tuple[Transform, ...]
    wheels: tuple[Wheel, Wheel]
    #: Publish the wheels' transforms on /tf from the wheel angles (robot_state_publisher's job for moving joints).
    wheel_tf: bool = True


@dataclass(frozen=True, slots=True)
class Ros2Options:
    frames: Frames
    pose_covariance: list[float]
    twist_covariance: list[float]
    publish_tf: bool
    joint_names: tuple[str, str]
    wheel_radius: float
    encoders: Encoders
    #: How error reports name the ROS inputs: the Zenoh key each arrives on.
    cmd_vel_key: str = "cmd_vel"
    cmd_vel_stamped_key: str = "cmd_vel"
    estop_key: str = "estop"
    #: The command source /cmd_vel drives as: ``<prefix>/cmd_vel/<source>``.
    source: str = Sources.ROS2
    #: A service call not confirmed within this (s) is answered success=false.
    service_timeout: float = 2.0
    #: The gateway's --poll-hz, which the robot link's measured poll rate is held against.
    expected_poll_hz: float = 50.0
    #: For the diagnostics: the node's fully qualified name, the flavour, the domain.
    node: str = "/blackmetal"
    flavor: str = "rmw_zenoh"
    domain_id: int = 0
    #: The Zenoh key of each service, which error reports name.
    service_keys: Mapping[str, str] = field(default_factory=dict)
    #: The ROS 2 distro whose rmw_zenoh formats the node speaks (for the diagnostics).
    distro: str = "jazzy"
    #: /robot_description, /tf_static and the wheels on /tf; None: another node publishes the robot model.
    robot: RobotModel | None = None
    #: For the diagnostics: the calibration in use and where /odom's covariance comes from.
    calibration: str = "none: the nominal constants"
    covariance: str = "fixed diagonals (--pose-covariance-diagonal, --twist-covariance-diagonal)"


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


# ------------------------------------------------------------------ windows
class WindowCount:
    """Events counted over the last :data:`WINDOW_S` seconds, and in all."""

    def __init__(self, window: float = WINDOW_S) -> None:
        self.window = window
        self.total = 0
        self._events: deque[tuple[float, int]] = deque()

    def add(self, now: float, count: int = 1) -> None:
        self._events.append((now, count))
        self.total += count

    def recent(self, now: float) -> int:
        while self._events and self._events[0][0] <= now - self.window:
            self._events.popleft()
        return sum(count for _, count in self._events)


@dataclass(slots=True)
class AdapterStats:
    """What the adapter itself did, for its diagnostic status."""

    commands: int = 0
    estops: int = 0
    bad_inputs: WindowCount = field(default_factory=WindowCount)
    confirmed: int = 0
    failed: WindowCount = field(default_factory=WindowCount)


# ------------------------------------------------------------------ diagnostics
def _yes(value: bool | None) -> str:
    return "unknown" if value is None else ("yes" if value else "no")


def _status(name: str, hardware_id: str, checks: list[tuple[Level, str]], ok: str, values: list[tuple[str, str]]) -> Diagnostic:
    """The worst level of ``checks`` and their reasons, worst first (``ok`` when there are none)."""
    checks = sorted(checks, key=lambda c: -int(c[0]))
    level = checks[0][0] if checks else Level.OK
    message = "; ".join(reason for _, reason in checks) if checks else ok
    return Diagnostic(level, name, message, hardware_id, tuple(values))


class Diagnostics:
    """The three statuses of ``/diagnostics`` from what it was fed last; pure, ``now`` passed in."""

    def __init__(self, keys: Keys, node: str, expected_poll_hz: float) -> None:
        self.keys = keys
        self.label = node.lstrip("/") or node
        self.expected_poll_hz = expected_poll_hz
        self.health: GatewayHealth | None = None
        self.health_at = -math.inf
        self._lost: deque[tuple[float, int, int]] = deque()  # (now, lost replies, polls) of each health
        self.gateway_alive: bool | None = None
        self.odometry_alive: bool | None = None
        self.pose_at = -math.inf
        self.poses = 0
        self.rejected = WindowCount()
        self.last_rejection = ""

    # inputs
    def on_health(self, health: GatewayHealth, now: float) -> None:
        if self.health is not None and health.source != self.health.source:
            self._lost.clear()  # another gateway run: its counters start over
        self.health, self.health_at = health, now
        self._lost.append((now, health.lost_replies, health.polls))

    def on_pose(self, now: float) -> None:
        self.pose_at = now
        self.poses += 1

    def on_error_report(self, report: ErrorReport, now: float) -> None:
        """The odometry's reports on the impulses key are its rejected (or repaired) samples."""
        if report.source == "odometry" and report.key == self.keys.impulses:
            self.rejected.add(now, max(1, report.suppressed))  # a rate-limit summary stands for its suppressed reports
            self.last_rejection = report.reason

    def on_alive(self, who: str, alive: bool) -> None:
        if who == "gateway":
            self.gateway_alive = alive
        elif who == "odometry":
            self.odometry_alive = alive

    # statuses
    def lost_in_window(self, now: float) -> tuple[int, int]:
        """(replies lost, polls) over the health reports of the last window."""
        while len(self._lost) > 1 and self._lost[0][0] <= now - WINDOW_S:
            self._lost.popleft()
        if len(self._lost) < 2:
            return 0, 0
        (_, lost0, polls0), (_, lost1, polls1) = self._lost[0], self._lost[-1]
        return max(0, lost1 - lost0), max(0, polls1 - polls0)

    def robot_link(self, now: float) -> Diagnostic:
        h, age = self.health, now - self.health_at
        name, hw = f"{self.label}: robot link", self.keys.prefix
        values = [("gateway alive", _yes(self.gateway_alive)), ("health age (s)", f"{age:.1f}" if h else "never")]
        if self.gateway_alive is False:
            return _status(name, hw, [(Level.ERROR, f"the gateway is not running (no {self.keys.alive_gateway})")], "", values)
        if h is None:
            return _status(name, hw, [(Level.STALE, f"no gateway health yet on {self.keys.health}")], "", values)
        lost, polls = self.lost_in_window(now)
        values += [
            ("control link", h.control.state),
            ("log link", h.log.state),
            ("poll rate (Hz)", f"{h.poll_hz:g}"),
            ("asked poll rate (Hz)", f"{self.expected_poll_hz:g}"),
            ("round trip (ms)", "none" if h.last_rtt_ms is None else f"{h.last_rtt_ms:.1f}"),
            ("lost replies", str(h.lost_replies)),
            (f"lost replies ({WINDOW_S:g} s)", str(lost)),
            ("e-stop", "engaged" if h.estop else "released"),
            ("e-stop since", h.estop_since_text()),
            ("e-stop by", h.estop_by or ""),
            ("command timeout active", _yes(h.cmd_timeout_active)),
            ("active source", h.active_source or "none"),
        ]
        if age > HEALTH_STALE_S:
            return _status(name, hw, [(Level.STALE, f"no gateway health for {age:.1f} s")], "", values)
        checks: list[tuple[Level, str]] = []
        if h.control.state != "connected":
            checks.append((Level.ERROR, f"control link {h.control.state}"))
        else:
            ratio = h.poll_hz / self.expected_poll_hz
            if ratio < POLL_WARN_RATIO:
                level = Level.ERROR if ratio < POLL_ERROR_RATIO else Level.WARN
                checks.append((level, f"polling at {h.poll_hz:g} Hz of {self.expected_poll_hz:g} Hz"))
        if h.conflict_with:
            checks.append((Level.ERROR, f"another gateway ({h.conflict_with}) on {self.keys.prefix}: commands refused"))
        if h.log.state != "connected":
            checks.append((Level.WARN, f"log link {h.log.state}"))
        if h.estop:
            checks.append((Level.WARN, f"e-stop engaged{h.estop_origin()}"))
        if h.last_rtt_ms is not None and h.last_rtt_ms > RTT_WARN_MS:
            checks.append((Level.ERROR if h.last_rtt_ms > RTT_ERROR_MS else Level.WARN, f"round trip {h.last_rtt_ms:.0f} ms"))
        if lost:
            level = Level.ERROR if lost >= LOST_ERROR_FRACTION * max(polls, 1) else Level.WARN
            checks.append((level, f"{lost} of {polls} replies lost in {WINDOW_S:g} s"))
        return _status(name, hw, checks, f"connected, polling at {h.poll_hz:g} Hz", values)

    def odometry(self, now: float) -> Diagnostic:
        age = now - self.pose_at
        recent = self.rejected.recent(now)
        name, hw = f"{self.label}: odometry", self.keys.prefix
        values = [
            ("odometry alive", _yes(self.odometry_alive)),
            ("pose age (s)", f"{age:.2f}" if self.poses else "never"),
            ("poses", str(self.poses)),
            (f"rejected samples ({WINDOW_S:g} s)", str(recent)),
            ("rejected samples", str(self.rejected.total)),
            ("last rejection", self.last_rejection or "none"),
        ]
        if self.odometry_alive is False:
            return _status(name, hw, [(Level.ERROR, f"the odometry is not running (no {self.keys.alive_odometry})")], "", values)
        if not self.poses:
            return _status(name, hw, [(Level.STALE, f"no pose yet on {self.keys.pose}")], "", values)
        if age > POSE_STALE_S:
            return _status(name, hw, [(Level.STALE, f"no pose for {age:.1f} s")], "", values)
        checks: list[tuple[Level, str]] = []
        if age > POSE_LATE_S:
            checks.append((Level.WARN, f"last pose {age:.1f} s ago"))
        if recent:
            level = Level.ERROR if recent >= REJECTED_ERROR_COUNT else Level.WARN
            checks.append((level, f"{recent} impulse samples rejected in {WINDOW_S:g} s"))
        return _status(name, hw, checks, "publishing poses", values)

    def adapter(self, now: float, stats: AdapterStats, options: Ros2Options, pending: int) -> Diagnostic:
        bad, failed = stats.bad_inputs.recent(now), stats.failed.recent(now)
        values = [
            ("flavor", options.flavor),
            ("distro", options.distro),
            ("node", options.node),
            ("domain id", str(options.domain_id)),
            ("cmd_vel to", self.keys.cmd_vel_of(options.source)),
            ("commands forwarded", str(stats.commands)),
            ("e-stops forwarded", str(stats.estops)),
            (f"bad ROS inputs ({WINDOW_S:g} s)", str(bad)),
            ("bad ROS inputs", str(stats.bad_inputs.total)),
            ("service calls confirmed", str(stats.confirmed)),
            ("service calls failed", str(stats.failed.total)),
            ("service calls pending", str(pending)),
            ("calibration", options.calibration),
            ("odometry covariance", options.covariance),
            ("robot model", "published (robot_description, tf_static, wheels on tf)" if options.robot else "not published"),
        ]
        checks: list[tuple[Level, str]] = []
        if bad:
            checks.append((Level.WARN, f"{bad} bad ROS inputs in {WINDOW_S:g} s (reported on {self.keys.errors})"))
        if failed:
            checks.append((Level.WARN, f"{failed} service calls failed in {WINDOW_S:g} s"))
        return _status(f"{self.label}: ROS 2 adapter", self.keys.prefix, checks, f"running; calibration {options.calibration}", values)


# ------------------------------------------------------------------ service calls
@dataclass(slots=True)
class PendingCall:
    """One service call waiting for the gateway's or the odometry's confirmation."""

    call: int
    service: str
    #: (sequence number, client GID) of an rmw_zenoh request, echoed in the reply's attachment; None: none came.
    reply_to: tuple[int, bytes] | None
    deadline: float
    engage: bool = False  # set_estop: the asked state
    repeat_at: float = math.inf  # set_estop: when to put again and ask the health again
    health: GatewayHealth | None = None  # set_estop: the latest health seen while waiting
    #: set_parameters(_atomically): the call's (name, value) pairs and the refusals decided before the gateway answers.
    parameters: list[tuple[str, RosValue]] = field(default_factory=list)
    refused: dict[int, str] = field(default_factory=dict)
    #: A parameter call that came before the gateway's table: its request, run once the table arrives.
    request: bytes | None = None


#: The ROS topics fed by a stream of the robot: published, and their streams followed, only while someone subscribes.
WATCHED_TOPICS = ("odom", "tf", "joint_states", "diagnostics")

SERVICE_TYPES = {SET_ESTOP: SET_BOOL, RESET_ODOMETRY: TRIGGER, **PARAMETER_SERVICES}
SET_CALLS = ("set_parameters", "set_parameters_atomically")


class Query:
    """What a query of the core asks, so its replies go where they belong."""

    HEALTH = "health"
    RESET = "reset"
    PARAMS = "params"
    PARAMS_SET = "params_set"


class Ros2Core:
    """Translates between the robot's keys and ROS topics and services (names relative to the node's namespace)."""

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
        self.wallclock = wallclock
        self.reporter = ErrorReporter("ros2", output.error, wallclock)
        self.joints = WheelJoints(options.encoders, options.wheel_radius)
        self.cmd_vel_target = keys.cmd_vel_of(options.source)
        self.diagnostics = Diagnostics(keys, options.node, options.expected_poll_hz)
        self.stats = AdapterStats()
        self.calls: dict[int, PendingCall] = {}
        self._queries: dict[int, tuple[str, int | None]] = {}  # query tag -> (what it asks, the call it serves)
        self.parameters = NodeParameters()
        #: The watched topics someone subscribes to; None until the edge reports (then everything is published).
        self.watched: set[str] | None = None
        self._following: frozenset[str] | None = None
        self._next_tag = 0
        self._next_diagnostics = -math.inf
        self._model_published = options.robot is None

    def publish_robot_model(self) -> None:
        """``/robot_description`` and ``/tf_static``, once: the edge's transient-local publishers keep them for late joiners."""
        robot = self.options.robot
        if robot is None:
            return
        self.output.ros(ROBOT_DESCRIPTION, self.codec.string(robot.urdf))
        self.output.ros(TF_STATIC, self.codec.transforms(self.wallclock(), robot.fixed))
        self._model_published = True

    def _reject(self, key: str, reason: str, snippet: str, now: float) -> None:
        """A bad ROS input: reported, counted, never forwarded."""
        self.stats.bad_inputs.add(now)
        self.reporter.report(key, reason, snippet, now=now)

    # --------------------------------------------------------------- blackmetal -> ROS
    def on_pose(self, payload: bytes, now: float) -> None:
        try:
            pose = decode(Pose, payload)
        except PayloadError as exc:
            self.reporter.report(self.keys.pose, str(exc), exc.excerpt, now=now)
            return
        self.diagnostics.on_pose(now)
        o = self.options
        if self._wants("odom"):
            self.output.ros("odom", self.codec.odometry(pose, o.frames, o.pose_covariance, o.twist_covariance))
        if o.publish_tf and self._wants("tf"):
            self.output.ros("tf", self.codec.transform(pose, o.frames))

    def on_impulses(self, payload: bytes, now: float) -> None:
        try:
            sample = decode(WheelImpulses, payload)
        except PayloadError as exc:
            self.reporter.report(self.keys.impulses, str(exc), exc.excerpt, now=now)
            return
        self.joints.feed(sample)
        if self._wants("joint_states"):
            cdr = self.codec.joint_state(sample.stamp, list(self.options.joint_names), self.joints.positions, self.joints.velocities)
            self.output.ros("joint_states", cdr)
        robot = self.options.robot
        if robot is not None and robot.wheel_tf and self.options.publish_tf and self._wants("tf"):
            wheels = [wheel.transform(angle) for wheel, angle in zip(robot.wheels, self.joints.positions, strict=True)]
            self.output.ros("tf", self.codec.transforms(sample.stamp, wheels))

    def on_health(self, payload: bytes, now: float) -> None:
        """The gateway's health (published, or the answer to our ``get``): diagnostics, and e-stop confirmations."""
        try:
            health = decode(GatewayHealth, payload)
        except PayloadError as exc:
            self.reporter.report(self.keys.health, str(exc), exc.excerpt, now=now)
            return
        self.diagnostics.on_health(health, now)
        for pending in list(self.calls.values()):
            if pending.service == SET_ESTOP:
                pending.health = health
                if health.estop == pending.engage:
                    state = "engaged" if pending.engage else "released"
                    self._finish(pending, True, f"e-stop {state} (confirmed by the gateway's health on {self.keys.health})", now)

    def on_error_report(self, payload: bytes, now: float) -> None:
        """A report on ``<prefix>/errors`` (ours included): the odometry's count as rejected samples."""
        try:
            report = decode(ErrorReport, payload)
        except PayloadError:
            return  # not ours to judge: whoever sent it reports nothing here
        self.diagnostics.on_error_report(report, now)

    def on_alive(self, who: str, alive: bool, now: float) -> None:
        """The gateway's or the odometry's liveliness token appeared (True) or went away (False)."""
        if who == "gateway" and alive and self.diagnostics.gateway_alive is False:
            self._ask_params()  # the gateway came back: its table may differ (another settings file, a restart)
        self.diagnostics.on_alive(who, alive)

    # --------------------------------------------------------------- parameters
    def start(self) -> None:
        """Once, when the node starts serving: ask the gateway for its parameter table, and follow only what is watched
        (the edge reports each topic's matching status from now on)."""
        self._ask_params()
        if self.watched is None:
            self.watched = set()
        self._follow()

    # --------------------------------------------------------------- who watches
    def _wants(self, topic: str) -> bool:
        return self.watched is None or topic in self.watched

    def needs(self) -> frozenset[str]:
        """The robot's streams the watched topics need: poses for /odom, /tf and /diagnostics; impulses for
        /joint_states and the wheels on /tf; error reports and the gateway's health for /diagnostics; the health, too,
        while a set_estop waits for it to confirm."""
        robot = self.options.robot
        wheel_tf = robot is not None and robot.wheel_tf and self.options.publish_tf and self._wants("tf")
        out = set()
        if self._wants("odom") or (self.options.publish_tf and self._wants("tf")) or self._wants("diagnostics"):
            out.add("pose")
        if self._wants("joint_states") or wheel_tf:
            out.add("impulses")
        if self._wants("diagnostics"):
            out.update(("errors", "health"))
        if any(pending.service == SET_ESTOP for pending in self.calls.values()):
            out.add("health")
        return frozenset(out)

    def _follow(self) -> None:
        if self.watched is None:
            return  # not started: the edge follows everything it declared
        needs = self.needs()
        if needs != self._following:
            self._following = needs
            self.output.follow(needs)

    def on_matched(self, topic: str, matched: bool, now: float) -> None:
        """Someone subscribes to ``topic`` now (``matched``), or nobody does any more: publish it, and follow what it needs,
        only while someone does."""
        if self.watched is None:
            self.watched = set()
        if matched:
            self.watched.add(topic)
        else:
            self.watched.discard(topic)
        self._follow()
        if matched and topic == "diagnostics":
            self._next_diagnostics = min(self._next_diagnostics, now)  # a new watcher gets the statuses at once

    def _ask_params(self) -> None:
        self._ask(Query.PARAMS, self.keys.params, None, None, self.options.service_timeout)

    def on_params(self, payload: bytes, now: float) -> None:
        """The gateway's parameter table (published on a change, or the answer to our get): /parameter_events."""
        try:
            table = decode(GatewayParams, payload)
        except PayloadError as exc:
            self.reporter.report(self.keys.params, str(exc), exc.excerpt, now=now)
            return
        self._take_params(table, now)

    def _take_params(self, table: GatewayParams, now: float) -> None:
        new, changed = self.parameters.on_table(table)
        if new or changed:
            self.output.ros(PARAMETER_EVENTS, self.codec.parameter_event(self.wallclock(), self.options.node, new, changed))
        waiting = [(p, p.request) for p in self.calls.values() if p.request is not None]  # calls that waited for it
        for pending, request in waiting:
            pending.request = None
            del self.calls[pending.call]
            self._run_parameter_call(pending, request, now)

    def _run_parameter_call(self, pending: PendingCall, cdr: bytes, now: float) -> None:
        """:meth:`_parameter_call`; a request that cannot be read is reported and refused."""
        try:
            self._parameter_call(pending, cdr, now)
        except PayloadError as exc:
            self._reject(self.options.service_keys.get(pending.service, pending.service), str(exc), exc.excerpt, now)
            self.stats.failed.add(now)
            self.output.service_refuse(pending.call, f"invalid request: {exc}")

    def _parameter_call(self, pending: PendingCall, cdr: bytes, now: float) -> None:
        """One of rclcpp's parameter services: answered from the table now, or (a set) when the gateway has answered.

        Before the gateway's table has arrived (the node has just started, or the gateway not yet), the call waits
        for it, at most the service timeout: ``ros2 param list`` at start-up lists the parameters, not nothing."""
        service, p, codec = pending.service, self.parameters, self.codec
        if not p.known:
            pending.request = cdr
            self.calls[pending.call] = pending
            self._ask_params()
            return
        if service == "list_parameters":
            prefixes, depth = codec.list_parameters_request(cdr)
            self._answer(pending, True, codec.list_parameters_response(*p.names(prefixes, depth)), now)
        elif service == "get_parameters":
            self._answer(pending, True, codec.get_parameters_response(p.values(codec.names_request(PARAMETER_SERVICES[service], cdr))), now)
        elif service == "get_parameter_types":
            names = codec.names_request(PARAMETER_SERVICES[service], cdr)
            self._answer(pending, True, codec.get_parameter_types_response(p.types(names)), now)
        elif service == "describe_parameters":
            names = codec.names_request(PARAMETER_SERVICES[service], cdr)
            self._answer(pending, True, codec.describe_parameters_response(p.describe(names)), now)
        else:
            pending.parameters = codec.set_parameters_request(PARAMETER_SERVICES[service], cdr)
            plan = p.plan(pending.parameters) if service == "set_parameters" else p.plan_atomically(pending.parameters)
            pending.refused = plan.refused
            for reason in plan.refused.values():
                self.reporter.report(self.options.service_keys.get(service, service), f"{service}: {reason}", "", now=now)
            if not plan.values:
                self._answer_set(pending, None, now)
                return
            self.calls[pending.call] = pending
            self._ask(Query.PARAMS_SET, self.keys.params_set, plan.payload(), pending.call, self.options.service_timeout)

    def _answer_set(self, pending: PendingCall, reply: ParamsSetReply | None, now: float, failure: str = "") -> None:
        """The SetParametersResult(s) of a set call: the refusals decided here, else the gateway's result for the name."""
        results = {r.name: r for r in reply.results} if reply is not None else {}
        answers: list[tuple[bool, str]] = []
        for i, (name, _) in enumerate(pending.parameters):
            if i in pending.refused:
                answers.append((False, pending.refused[i]))
            elif name in results:
                answers.append((results[name].successful, results[name].reason))
            else:
                answers.append((False, failure or f"the gateway did not answer for {name}"))
        if pending.service == "set_parameters_atomically":
            ok = bool(answers) and all(good for good, _ in answers)
            reasons = "; ".join(dict.fromkeys(reason for good, reason in answers if not good and reason))
            if not ok and any(good for good, _ in answers):
                reasons += " (the gateway set the others: it sets each value on its own)"
            self._answer(pending, ok, self.codec.set_parameters_atomically_response(ok, reasons), now)
        else:
            ok = all(good for good, _ in answers)
            self._answer(pending, ok, self.codec.set_parameters_response(answers), now)

    # --------------------------------------------------------------- ROS -> blackmetal
    def on_cmd_vel(self, cdr: bytes, now: float, stamped: bool = False) -> None:
        """A ``/cmd_vel`` sample, ``geometry_msgs/Twist`` or (``stamped``) ``TwistStamped``, forwarded as the source's command.

        A stamped command older than the gateway's command timeout (its
        header stamp against the wall clock; a zero stamp means now, as
        diff_drive_controller reads it) is refused and reported: the robot
        must not act on a command its publisher gave up on.
        """
        self.take_cmd_vel(cdr, now, stamped, report=True)

    def take_cmd_vel(self, cdr: bytes, now: float, stamped: bool = False, report: bool = False) -> bool:
        """Forward an acceptable ``/cmd_vel`` sample (see :meth:`on_cmd_vel`); whether it was forwarded.

        Without ``report`` a refusal changes nothing and returns False, so
        that the host's direct take (on Zenoh's thread, which must not
        publish an error report) leaves the sample to :meth:`on_cmd_vel` on
        the loop, which refuses it again and reports why.
        """
        key = self.options.cmd_vel_stamped_key if stamped else self.options.cmd_vel_key
        try:
            if stamped:
                twist, stamp = self.codec.twist_stamped(cdr)
            else:
                twist, stamp = self.codec.twist(cdr), 0.0
        except PayloadError as exc:
            if report:
                self._reject(key, str(exc), exc.excerpt, now)
            return False
        timeout = self._cmd_timeout()
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

    def _cmd_timeout(self) -> float:
        """The gateway's command timeout: from its parameters (published on each change), else its last health."""
        param = self.parameters.table.get("cmd_timeout")
        if param is not None and isinstance(param.value, (int, float)) and not isinstance(param.value, bool):
            return float(param.value)
        health = self.diagnostics.health
        return DEFAULT_CMD_TIMEOUT if health is None else health.cmd_timeout

    def on_estop(self, cdr: bytes, now: float) -> None:
        try:
            estop = self.codec.estop(cdr)
        except PayloadError as exc:
            self._reject(self.options.estop_key, str(exc), exc.excerpt, now)
            return
        self.stats.estops += 1
        self.output.blackmetal(self.keys.estop_for(estop.engaged), encode(estop))

    # --------------------------------------------------------------- services
    def on_service_request(self, service: str, call: int, cdr: bytes, request_attachment: bytes | None, now: float) -> None:
        """A call of ``service`` (``set_estop`` or ``reset_odometry``); answered now if refused, else when confirmed."""
        key = self.options.service_keys.get(service, service)
        if service not in SERVICE_TYPES:
            self.output.service_refuse(call, f"no service {service!r} here")
            return
        reply_to = None
        if request_attachment is not None:
            try:
                sequence, _, gid = parse_attachment(request_attachment)
                if sequence < 0:
                    raise ValueError(f"sequence number {sequence} is negative")
            except ValueError as exc:
                reason = f"service request with an attachment that is not rmw_zenoh's: {exc}"
                self._reject(key, reason, excerpt(request_attachment), now)
                self.stats.failed.add(now)
                self.output.service_refuse(call, reason)
                return
            reply_to = (sequence, gid)
        pending = PendingCall(call, service, reply_to, deadline=now + self.options.service_timeout)
        if service in PARAMETER_SERVICES:
            if len(self.calls) >= MAX_PENDING_CALLS and (service in SET_CALLS or not self.parameters.known):
                self.stats.failed.add(now)
                self.output.service_refuse(call, f"{MAX_PENDING_CALLS} calls are already waiting for their answer; call again")
                return
            self._run_parameter_call(pending, cdr, now)
            return
        try:
            if service == SET_ESTOP:
                pending.engage = self.codec.set_bool(cdr)
            else:
                self.codec.trigger(cdr)
        except PayloadError as exc:
            self._reject(key, str(exc), exc.excerpt, now)
            self._finish(pending, False, f"invalid request: {exc}", now)
            return
        if len(self.calls) >= MAX_PENDING_CALLS:
            self._finish(pending, False, f"{MAX_PENDING_CALLS} calls are already waiting for their confirmation; call again", now)
            return
        self.calls[call] = pending
        if service == SET_ESTOP:
            self._follow()
            for other in list(self.calls.values()):  # an older call asking the opposite must stop putting it
                if other.service == SET_ESTOP and other.engage != pending.engage:
                    state = "on" if pending.engage else "off"
                    self._finish(other, False, f"superseded: set_estop {state} was called since", now)
            self._put_estop(pending, now)
        else:
            self._ask(Query.RESET, self.keys.odometry_reset, None, call, self.options.service_timeout)

    def _put_estop(self, pending: PendingCall, now: float) -> None:
        """Put the asked e-stop state and ask the gateway's health; again every ESTOP_REPEAT_S until confirmed."""
        self.output.blackmetal(self.keys.estop_for(pending.engage), encode(EStop(engaged=pending.engage)))
        self._ask(Query.HEALTH, self.keys.health, None, None, max(min(pending.deadline - now, 5 * ESTOP_REPEAT_S), ESTOP_REPEAT_S))
        pending.repeat_at = now + ESTOP_REPEAT_S

    def _ask(self, what: str, key: str, payload: bytes | None, call: int | None, timeout: float) -> None:
        self._next_tag += 1
        self._queries[self._next_tag] = (what, call)
        self.output.query(key, payload, self._next_tag, timeout)

    def on_query_reply(self, tag: int, ok: bool, payload: bytes, now: float) -> None:
        """One reply to our query ``tag`` (``ok`` False: an error reply, ``payload`` its text)."""
        if tag not in self._queries:
            return
        what, call = self._queries[tag]
        if what == Query.HEALTH:
            if ok:
                self.on_health(payload, now)
            return
        if what == Query.PARAMS:
            if ok:
                self.on_params(payload, now)
            return
        pending = self.calls.get(call) if call is not None else None
        if pending is None:
            return
        if what == Query.PARAMS_SET:
            if not ok:
                reason = payload.decode(errors="replace") or "no reason given"
                self._answer_set(pending, None, now, f"the gateway on {self.keys.prefix!r} refused the set: {reason}")
                return
            try:
                reply = decode(ParamsSetReply, payload)
            except PayloadError as exc:
                self._answer_set(pending, None, now, f"the gateway answered something that is not a ParamsSetReply: {exc}")
                return
            self._take_params(reply.params, now)
            self._answer_set(pending, reply, now)
            return
        if not ok:
            self._finish(pending, False, f"the odometry refused the reset: {payload.decode(errors='replace')}", now)
            return
        try:
            pose = decode(Pose, payload)
        except PayloadError as exc:
            self._finish(pending, False, f"the odometry answered something that is not a pose: {exc}", now)
            return
        if max(abs(pose.x), abs(pose.y), abs(pose.yaw)) <= RESET_TOLERANCE:
            self._finish(pending, True, f"odometry reset to x=0 y=0 yaw=0 (confirmed by the odometry on {self.keys.odometry_reset})", now)
        else:
            self._finish(pending, False, f"the odometry answered x={pose.x:g} y={pose.y:g} yaw={pose.yaw:g} after the reset", now)

    def on_query_done(self, tag: int, now: float) -> None:
        """No more replies to ``tag`` will come: a reset or a parameter set nobody answered fails now."""
        what, call = self._queries.pop(tag, (Query.HEALTH, None))
        pending = self.calls.get(call) if call is not None else None
        if pending is not None and what == Query.PARAMS_SET:
            where = f"no gateway answered on {self.keys.params_set} (is it running on prefix {self.keys.prefix}?): nothing was set"
            self._answer_set(pending, None, now, where)
        elif pending is not None:
            self._finish(
                pending, False, f"no odometry answered on {self.keys.odometry_reset} (is it running on prefix {self.keys.prefix}?)", now
            )

    def _finish(self, pending: PendingCall, success: bool, message: str, now: float) -> None:
        """Answer ``pending`` once, with the std_srvs response."""
        self._answer(pending, success, self.codec.service_response(SERVICE_TYPES[pending.service], success, message), now)

    def _answer(self, pending: PendingCall, success: bool, cdr: bytes, now: float) -> None:
        """Answer ``pending`` once, with ``cdr`` and (rmw_zenoh) the reply attachment."""
        self.calls.pop(pending.call, None)
        if pending.service == SET_ESTOP:
            self._follow()  # the health is followed no longer, unless /diagnostics needs it
        if success:
            self.stats.confirmed += 1
        else:
            self.stats.failed.add(now)
        reply_attachment = None
        if pending.reply_to is not None:
            sequence, gid = pending.reply_to
            reply_attachment = attachment(sequence, round(self.wallclock() * 1e9), gid)
        self.output.service_reply(pending.call, cdr, reply_attachment)

    def _timed_out(self, pending: PendingCall, now: float) -> None:
        limit = f"{self.options.service_timeout:g} s"
        if pending.request is not None:  # it waited for the gateway's table, which never came
            self.calls.pop(pending.call, None)
            self.stats.failed.add(now)
            reason = (
                f"the gateway's parameters did not arrive within {limit} ({self.keys.params}): is it running on prefix {self.keys.prefix}?"
            )
            self.output.service_refuse(pending.call, reason)
            return
        if pending.service in SET_CALLS:
            self._answer_set(pending, None, now, f"the gateway did not answer within {limit} ({self.keys.params_set}); nothing known set")
            return
        if pending.service == RESET_ODOMETRY:
            self._finish(pending, False, f"the odometry did not answer the reset within {limit} ({self.keys.odometry_reset})", now)
            return
        state = "on" if pending.engage else "off"
        if pending.health is None:
            seen = f"no health on {self.keys.health}: is the gateway running on prefix {self.keys.prefix}?"
        else:
            seen = f"its health still says estop={str(pending.health.estop).lower()}"
        self._finish(pending, False, f"the gateway did not confirm the e-stop {state} within {limit} ({seen})", now)

    # --------------------------------------------------------------- timers
    def statuses(self, now: float) -> list[Diagnostic]:
        d = self.diagnostics
        return [d.robot_link(now), d.odometry(now), d.adapter(now, self.stats, self.options, len(self.calls))]

    def tick(self, now: float) -> None:
        """Run what is due at ``now``: the robot model (first tick), call deadlines and e-stop repeats, diagnostics,
        error-report summaries."""
        if not self._model_published:
            self.publish_robot_model()
        for pending in list(self.calls.values()):
            if now >= pending.deadline:
                self._timed_out(pending, now)
            elif now >= pending.repeat_at:
                self._put_estop(pending, now)
        if now >= self._next_diagnostics:
            if self._wants("diagnostics"):  # nobody subscribes: nothing encoded
                self.output.ros("diagnostics", self.codec.diagnostics(self.wallclock(), self.statuses(now)))
            due = self._next_diagnostics + DIAGNOSTICS_PERIOD_S
            self._next_diagnostics = due if due > now else now + DIAGNOSTICS_PERIOD_S
        self.reporter.tick(now)

    def next_deadline(self) -> float:
        """When :meth:`tick` has something to do next."""
        diagnostics = self._next_diagnostics if self._wants("diagnostics") else math.inf  # nobody watches: no timer
        deadline = min(diagnostics, self.reporter.next_deadline())
        if self.calls:  # asked after every pose: the common case, no call pending, builds nothing
            deadline = min(deadline, *(min(p.deadline, p.repeat_at) for p in self.calls.values()))
        return deadline
