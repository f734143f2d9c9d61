"""The Black Metal robot as numbers and formulas: the one place they are computed.

The gateway (twist to wheel commands), the odometry (impulses to motion, streaming and batch), the simulator (motion to
impulses, true pose), the log synthesiser and the bench all take the robot's constants and formulas from here, so a
calibration or a sign convention changes in one place. The formulas are plain arithmetic, so each works on floats and on
numpy arrays.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar
from xml.sax.saxutils import quoteattr

from blackmetal.schemas import ConfigError, WheelImpulses

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

#: Encoder impulses per metre of rim travel (= impulses/s per m/s), left wheel.
IMPULSES_PER_METER_LEFT = 1012.53636364
#: Same for the right wheel. Its encoder is mirrored: forward motion reads negative.
IMPULSES_PER_METER_RIGHT = 1053.67588345
#: The right wheel's encoder counts backwards when the wheel drives forward.
RIGHT_ENCODER_MIRRORED = True
#: The robot's own limit per wheel (m/s); a reading above it is a glitch.
MAX_WHEEL_SPEED = 0.8
#: Distance between the wheels (m), from the original driver's configuration.
WHEEL_SEPARATION = 0.5
#: Wheel radius (m).
WHEEL_RADIUS = 0.1
#: The robot stops its wheels by itself after this long without a motion command (s).
ROBOT_WATCHDOG_S = 10.0
#: TCP ports of the robot's control computer.
CONTROL_PORT = 665
LOG_PORT = 664

Num = TypeVar("Num", float, "NDArray[np.float64]")


@dataclass(frozen=True, slots=True, kw_only=True)
class WheelSpeeds:
    """Wheel rim speeds in m/s, natural sign (forward positive on both wheels).

    Left, then right, and keyword-only, like every wheel pair in blackmetal: a positional slip cannot swap the wheels.
    The robot's right-then-left wire order lives only in :mod:`blackmetal.wire`.
    """

    left: float
    right: float

    def rounded(self) -> "WheelSpeeds":
        """As the wire carries them (6 decimals), so equal commands compare equal."""
        return WheelSpeeds(left=round(self.left, 6) + 0.0, right=round(self.right, 6) + 0.0)

    def scaled(self, gain: "WheelGain") -> "WheelSpeeds":
        return WheelSpeeds(left=self.left * gain.left, right=self.right * gain.right)

    @property
    def is_zero(self) -> bool:
        return self.right == 0.0 and self.left == 0.0


STANDSTILL = WheelSpeeds(left=0.0, right=0.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class WheelGain:
    """A per-wheel factor (left, right), e.g. calibrated over nominal impulses per metre."""

    left: float = 1.0
    right: float = 1.0

    @property
    def is_unity(self) -> bool:
        return self.left == 1.0 and self.right == 1.0


UNITY_GAIN = WheelGain()


@dataclass(frozen=True, slots=True)
class Encoders:
    """How encoder impulses relate to rim travel: impulses per metre of each wheel, and the mirroring."""

    impulses_per_meter_left: float = IMPULSES_PER_METER_LEFT
    impulses_per_meter_right: float = IMPULSES_PER_METER_RIGHT
    mirror_right: bool = RIGHT_ENCODER_MIRRORED

    def to_speeds(self, left: Num, right: Num) -> tuple[Num, Num]:
        """Impulses (per second) as the robot reports them -> rim speeds (m/s), forward positive."""
        sign = -1.0 if self.mirror_right else 1.0
        return left / self.impulses_per_meter_left, sign * right / self.impulses_per_meter_right

    def to_impulses(self, left: Num, right: Num) -> tuple[Num, Num]:
        """Rim speeds (m/s) or travels (m) -> impulses as the robot reports them (right mirrored), unrounded."""
        sign = -1.0 if self.mirror_right else 1.0
        return left * self.impulses_per_meter_left, sign * right * self.impulses_per_meter_right

    def commanded_travel(self, left: int, right: int) -> tuple[float, float]:
        """Rim travel (m) of a SET_LR_WHEEL_POSITION command: impulses in the natural sign, like speeds on the wire."""
        return left / self.impulses_per_meter_left, right / self.impulses_per_meter_right


NOMINAL_ENCODERS = Encoders()

#: Wheel angles are not integrated across a gap longer than this (s): a lost link is not motion.
MAX_JOINT_GAP_S = 0.5


@dataclass(slots=True)
class WheelAngles:
    """Wheel angles (rad) from the impulses' wheel speeds, trapezoid rule, never across a gap (ROS 2's /joint_states and
    Foxglove's turning wheels); ``wrap``: kept within -pi..pi."""

    wrap: bool = False
    positions: list[float] = field(default_factory=lambda: [0.0, 0.0])
    velocities: list[float] = field(default_factory=lambda: [0.0, 0.0])
    _last: float | None = None

    def feed(self, sample: WheelImpulses, encoders: Encoders, radius: float) -> None:
        left, right = encoders.to_speeds(float(sample.left), float(sample.right))
        velocities = [left / radius, right / radius]
        now = sample.mono if sample.mono is not None else sample.stamp
        if self._last is not None and 0.0 < now - self._last <= MAX_JOINT_GAP_S:
            dt = now - self._last
            for i in (0, 1):
                angle = self.positions[i] + 0.5 * (self.velocities[i] + velocities[i]) * dt
                self.positions[i] = math.remainder(angle, math.tau) if self.wrap else angle
        self._last = now
        self.velocities = velocities


def twist_to_wheels(v: float, w: float, separation: float, max_wheel_speed: float) -> tuple[WheelSpeeds, bool]:
    """Wheel speeds for forward speed ``v`` (m/s) and turn rate ``w`` (rad/s, + is left).

    ``right = v + w*L/2``, ``left = v - w*L/2``. If either exceeds ``max_wheel_speed``, both are scaled by the same
    factor so the robot follows the same arc, only slower (clamping each wheel alone would bend the path). Returns the
    speeds and whether they were scaled.
    """
    half = 0.5 * w * separation
    right = v + half
    left = v - half
    peak = max(abs(right), abs(left))
    if peak <= max_wheel_speed:
        return WheelSpeeds(left=left, right=right), False
    scale = max_wheel_speed / peak
    return WheelSpeeds(left=left * scale, right=right * scale), True


def wheels_to_twist(left: Num, right: Num, separation: float) -> tuple[Num, Num]:
    """Forward speed and turn rate of rim speeds (the inverse of :func:`twist_to_wheels`)."""
    return 0.5 * (right + left), (right - left) / separation


def arc_step(x: float, y: float, yaw: float, d_left: float, d_right: float, separation: float) -> tuple[float, float, float]:
    """Move a differential-drive pose by wheel travels ``d_left``/``d_right`` along the exact arc.

    Chord form: length ``ds * sin(h)/h`` at heading ``yaw + h`` with ``h`` half the turn; exact for any turn and well
    conditioned as the turn goes to zero, where it becomes the straight line. The simulator's truth and the odometry
    both move this way.
    """
    ds = 0.5 * (d_left + d_right)
    dth = (d_right - d_left) / separation
    half = 0.5 * dth
    chord = ds * sin_ratio(half)
    heading = yaw + half
    return x + chord * math.cos(heading), y + chord * math.sin(heading), yaw + dth


def arc_deltas(
    yaw_before: "NDArray[np.float64]", d_left: "NDArray[np.float64]", d_right: "NDArray[np.float64]", separation: float
) -> tuple["NDArray[np.float64]", "NDArray[np.float64]", "NDArray[np.float64]"]:
    """:func:`arc_step` for many steps at once: the x, y and yaw change of each step (numpy)."""
    import numpy as np

    ds = 0.5 * (d_left + d_right)
    dth = (d_right - d_left) / separation
    half = 0.5 * dth
    chord = ds * _sin_ratio(half)
    heading = yaw_before + half
    return chord * np.cos(heading), chord * np.sin(heading), dth


def arc_path(
    d_left: "NDArray[np.float64]", d_right: "NDArray[np.float64]", separation: float
) -> tuple["NDArray[np.float64]", "NDArray[np.float64]", "NDArray[np.float64]"]:
    """x, y and unwrapped yaw after each of many :func:`arc_step` moves from (0, 0, 0) (numpy, one pass).

    The whole of the odometry's geometry for a replay, and what a calibration evaluates a thousand times: the fewest
    array operations that keep :func:`arc_step`'s arithmetic.
    """
    import numpy as np

    dth = (d_right - d_left) / separation
    yaw = np.cumsum(dth)
    half = 0.5 * dth
    heading = half.copy()
    heading[1:] += yaw[:-1]  # the yaw before each step, plus half its turn
    chord = 0.5 * (d_left + d_right)
    chord *= _sin_ratio(half)

    def along(trig: Any) -> "NDArray[np.float64]":
        moves = trig(heading)
        moves *= chord
        return np.cumsum(moves, out=moves)

    x, y = both(lambda: along(np.cos), lambda: along(np.sin), len(heading))
    return x, y, yaw


#: Arrays at least this long are worth a second thread (numpy releases the GIL inside its loops).
PARALLEL_MIN = 100_000

_First = TypeVar("_First")
_Second = TypeVar("_Second")


def both(first: Callable[[], _First], second: Callable[[], _Second], size: int) -> tuple[_First, _Second]:
    """``(first(), second())``, the first on a second thread when ``size`` is large: two independent numpy computations in
    the time of one on a two-core machine."""
    if size < PARALLEL_MIN:
        return first(), second()
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(1) as pool:
        pending = pool.submit(first)
        other = second()
        return pending.result(), other


#: Below this |h|, sin(h)/h is its Taylor polynomial to h**8; the next term is < 3e-21.
_SIN_RATIO_SERIES = 0.05


def sin_ratio(half: float) -> float:
    """sin(h)/h, 1 at 0: the same polynomial and threshold as the numpy form, so streaming and batch agree to the bit."""
    if abs(half) > _SIN_RATIO_SERIES:
        return math.sin(half) / half
    h2 = half * half
    return (((h2 * (1.0 / 362880.0) - 1.0 / 5040.0) * h2 + 1.0 / 120.0) * h2 - 1.0 / 6.0) * h2 + 1.0


def _sin_ratio(half: "NDArray[np.float64]") -> "NDArray[np.float64]":
    """:func:`sin_ratio` over an array, in place-friendly steps (ten times cheaper than sin for odometry's small half-turns)."""
    import numpy as np

    h2 = half * half
    out = h2 * (1.0 / 362880.0)
    out -= 1.0 / 5040.0
    out *= h2
    out += 1.0 / 120.0
    out *= h2
    out -= 1.0 / 6.0
    out *= h2
    out += 1.0
    large = np.flatnonzero(h2 > _SIN_RATIO_SERIES**2)
    if large.size:
        out[large] = np.sin(half[large]) / half[large]
    return out


# The robot as a URDF (docs/ros2.md, docs/commands/tools.md "urdf"): the wheels turn about +y, so a positive angle
# drives forward. The robot's documentation gives its wheel separation and radius, not its body: the chassis box and the
# rear caster are drawn from those two numbers, and the URDF's comment says so.


@dataclass(frozen=True, slots=True)
class Body:
    """What the URDF draws around the wheels; derived from the wheel geometry unless given."""

    wheel_separation: float = WHEEL_SEPARATION
    wheel_radius: float = WHEEL_RADIUS
    wheel_width: float = 0.04
    #: The chassis box: as long as the wheels are apart, as wide as the gap between the wheels, a wheel radius high.
    length: float | None = None
    width: float | None = None
    height: float | None = None

    def check(self) -> Body:
        for name in ("wheel_separation", "wheel_radius", "wheel_width"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0 < value < 10):
                raise ConfigError(f"{name} must be a positive length in metres (below 10 m), got {value!r}")
        if self.wheel_width >= self.wheel_separation:
            raise ConfigError(f"wheel_width {self.wheel_width} must be less than the wheel separation {self.wheel_separation}")
        return self

    @property
    def box(self) -> tuple[float, float, float]:
        length = self.length if self.length is not None else self.wheel_separation
        width = self.width if self.width is not None else self.wheel_separation - 2 * self.wheel_width
        height = self.height if self.height is not None else self.wheel_radius
        return length, width, height


def _f(value: float) -> str:
    return f"{value:.6g}"


@dataclass(frozen=True, slots=True)
class Joint:
    """One joint of the URDF, as robot_state_publisher turns it into a transform: parent -> child at ``xyz`` (m)."""

    name: str
    kind: str  # "fixed" or "continuous"
    parent: str
    child: str
    xyz: tuple[float, float, float]


def joints(body: Body | None = None, *, left_joint: str = "left_wheel_joint", right_joint: str = "right_wheel_joint") -> list[Joint]:
    """The URDF's joints, unprefixed: what ``/tf_static`` (the fixed ones) and ``/tf`` (the wheels) carry, from one place.

    ``base_footprint`` on the floor, ``base_link`` at the axle height above it, the wheels on the axle at plus and minus
    half the separation (the left one at +y), the caster behind, touching the floor.
    """
    body = (body or Body()).check()
    r, half = body.wheel_radius, body.wheel_separation / 2
    return [
        Joint("base_joint", "fixed", "base_footprint", "base_link", (0.0, 0.0, r)),
        Joint(left_joint, "continuous", "base_link", "left_wheel", (0.0, half, 0.0)),
        Joint(right_joint, "continuous", "base_link", "right_wheel", (0.0, -half, 0.0)),
        Joint("caster_joint", "fixed", "base_link", "caster", (-0.8 * body.box[0] / 2, 0.0, r / 2 - r)),
    ]


def urdf(
    body: Body | None = None,
    *,
    left_joint: str = "left_wheel_joint",
    right_joint: str = "right_wheel_joint",
    frame_prefix: str = "",
    name: str = "blackmetal",
) -> str:
    """The URDF text (one robot): links ``base_footprint``, ``base_link``, the wheels and the caster, each ``frame_prefix``-ed."""
    body = (body or Body()).check()
    r = body.wheel_radius
    length, width, height = body.box
    p = frame_prefix

    wheel = (f'<cylinder radius="{_f(r)}" length="{_f(body.wheel_width)}"/>', "0 0 0", "1.5708 0 0")
    #: Each joint's child link: its geometry, and its origin's xyz and rpy.
    shapes = {
        "base_link": (f'<box size="{_f(length)} {_f(width)} {_f(height)}"/>', f"0 0 {_f(height / 2)}", "0 0 0"),
        "left_wheel": wheel,
        "right_wheel": wheel,
        "caster": (f'<sphere radius="{_f(r / 2)}"/>', "0 0 0", "0 0 0"),
    }
    parts = []
    for j in joints(body, left_joint=left_joint, right_joint=right_joint):
        geometry, xyz, rpy = shapes[j.child]
        shape = f'<origin xyz="{xyz}" rpy="{rpy}"/><geometry>{geometry}</geometry>'
        axis_xml = '\n    <axis xyz="0 1 0"/>' if j.kind == "continuous" else ""
        joint_name = j.name if j.kind == "continuous" else p + j.name  # the wheels are named as in /joint_states
        parts.append(
            f"  <link name={quoteattr(p + j.child)}>\n"
            f"    <visual>{shape}</visual>\n"
            f"    <collision>{shape}</collision>\n"
            f"  </link>\n"
            f"  <joint name={quoteattr(joint_name)} type={quoteattr(j.kind)}>\n"
            f"    <parent link={quoteattr(p + j.parent)}/>\n    <child link={quoteattr(p + j.child)}/>\n"
            f'    <origin xyz="{" ".join(_f(v) for v in j.xyz)}" rpy="0 0 0"/>{axis_xml}\n'
            f"  </joint>\n"
        )
    return (
        '<?xml version="1.0"?>\n'
        f"<!-- {name}: made by blackmetal from its robot model: wheel separation {_f(body.wheel_separation)} m, "
        f"wheel radius {_f(r)} m. The body box and the rear caster are drawn from those two numbers, "
        "not measured. -->\n"
        f"<robot name={quoteattr(name)}>\n"
        f"  <link name={quoteattr(p + 'base_footprint')}/>\n" + "".join(parts) + "</robot>\n"
    )


# The calibration file ``blackmetal calibrate -o FILE`` writes (docs/ros2.md, "/odom's covariance"): settings every
# service takes, and the residuals as comment lines, since a service refuses settings it does not know.

#: How a residual line starts; the name and the value follow (``# residuals.x_m = 0.00123``).
RESIDUAL_LINE = "# residuals."
_RESIDUAL = re.compile(r"^# residuals\.([a-z_]+) = ([-+0-9.eE]+|nan|inf)\s*$")


@dataclass(frozen=True, slots=True)
class Residuals:
    """The calibrated odometry against the reference over the recordings: root mean squares after the fit."""

    steps: int  # odometry steps compared with the reference
    path_m: float  # path driven over them (m)
    x_m: float  # position, along the odometry frame's x and y (m)
    y_m: float
    yaw_rad: float  # heading (rad)
    v_mps: float  # forward speed (m/s)
    w_radps: float  # turn rate (rad/s)

    def lines(self) -> list[str]:
        """The comment lines the calibration file carries them in."""
        return [f"{RESIDUAL_LINE}{name} = {getattr(self, name):.6g}" for name in _RESIDUAL_NAMES]


_RESIDUAL_NAMES = [f.name for f in fields(Residuals)]


@dataclass(frozen=True, slots=True)
class Calibration:
    """A calibration file: where it is, what its first comment says of it, its constants, its residuals if measured."""

    path: str
    note: str
    wheel_separation: float
    impulses_left: float
    impulses_right: float
    residuals: Residuals | None


def read_calibration(path: str) -> Calibration:
    """The calibration file ``blackmetal calibrate -o`` wrote; ConfigError in one sentence when it is not one."""
    import tomllib

    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read the calibration file {path}: {exc.strerror}") from None
    try:
        values = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"calibration file {path} is not valid TOML: {exc}") from None
    constants = {}
    for name in ("wheel_separation", "impulses_left", "impulses_right"):
        value = values.get(name)
        if not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
            raise ConfigError(f"calibration file {path} has no positive {name} (is it the output of blackmetal calibrate -o?)")
        constants[name] = float(value)
    found = {match[1]: match[2] for line in text.splitlines() if (match := _RESIDUAL.match(line))}
    residuals = None
    if found:
        names = _RESIDUAL_NAMES
        missing = [n for n in names if n not in found]
        if missing:
            raise ConfigError(f"calibration file {path} lacks the residual lines {missing} (write it again with blackmetal calibrate -o)")
        numbers = {n: float(found[n]) for n in names}
        if not all(math.isfinite(v) and v >= 0 for v in numbers.values()) or numbers["steps"] < 1:
            raise ConfigError(f"calibration file {path}: residuals must be finite and not negative, got {numbers}")
        residuals = Residuals(steps=int(numbers.pop("steps")), **numbers)
    note = next((line.lstrip("# ").strip() for line in text.splitlines() if line.startswith("#")), "")
    return Calibration(path, note, residuals=residuals, **constants)
