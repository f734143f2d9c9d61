"""The gateway's settings: one typed model; its options, help and file names come from these fields."""

from __future__ import annotations

from dataclasses import dataclass, field

from blackmetal import robot_model as model
from blackmetal.runtime.settings import check_positive, setting
from blackmetal.runtime.zenoh_setup import ZenohSettings
from blackmetal.schemas import DEFAULT_PREFIX, ConfigError, validate_prefix

from .arbiter import DEFAULT_SOURCES, Arbiter, arbiter_of
from .latch import FileLatchStore, default_state_dir, latch_path
from .safety import SafetySettings


def when_killed(robot: str) -> str:
    """What stops the robot if this gateway is killed (SIGKILL, an OOM kill, a crash): said once, at start."""
    return (
        f"if this gateway is killed, the robot keeps its last command until its own {model.ROBOT_WATCHDOG_S:g} s watchdog: "
        f"blackmetal up and the systemd unit's ExecStopPost then run `blackmetal stop-robot`; started by hand, run "
        f"`blackmetal stop-robot --robot {robot}` yourself"
    )


#: The gateway's settings the safety governor takes as they are.
SAFETY_SETTINGS = ("wheel_separation", "max_wheel_speed", "cmd_timeout", "keepalive", "linear_accel", "angular_accel", "max_command_hz")
#: Upper bounds of the time settings, each with why: beyond them a setting is a typo, not a robot's need.
TIME_LIMITS = (
    ("cmd_timeout", 60.0, "a deadman that waits longer than a minute stops nothing (0 disables it, knowingly)"),
    ("reply_timeout", 10.0, "the robot answers within milliseconds; beyond its 10 s watchdog a lost reply is never noticed"),
    ("silence_timeout", 60.0, "a silent robot would stay unnoticed for longer than a minute"),
    ("log_silence_timeout", 60.0, "the robot reports its state about once a second"),
    ("connect_timeout", 60.0, "a robot on the network answers a connection within seconds"),
    ("health_period", 60.0, "views and `blackmetal robots` mark a robot lost after 3 s without health"),
)


@dataclass(slots=True)
class GatewaySettings:
    robot: str = setting("127.0.0.1", "robot address (a local simulator by default; never a lab address)", metavar="HOST")
    control_port: int = setting(model.CONTROL_PORT, "robot control port", metavar="PORT")
    log_port: int = setting(model.LOG_PORT, "robot log port", metavar="PORT")
    poll_hz: float = setting(50.0, "wheel-speed polls per second", metavar="HZ")
    wheel_separation: float = setting(model.WHEEL_SEPARATION, "distance between the wheels, m", metavar="M")
    impulses_left: float = setting(
        model.IMPULSES_PER_METER_LEFT,
        "calibrated impulses per metre, left wheel (commands are corrected by this over the nominal)",
        metavar="N",
    )
    impulses_right: float = setting(model.IMPULSES_PER_METER_RIGHT, "calibrated impulses per metre, right wheel", metavar="N")
    max_wheel_speed: float = setting(
        model.MAX_WHEEL_SPEED, "per-wheel limit, m/s; faster commands are scaled keeping the curvature", metavar="M/S"
    )
    cmd_timeout: float = setting(0.5, "brake after this many seconds without cmd_vel; 0 disables", metavar="S")
    keepalive: float = setting(5.0, "repeat an unchanged motion command this often, s (the robot stops by itself after 10 s)", metavar="S")
    linear_accel: float | None = setting(None, "acceleration limit, m/s^2 (default off)", metavar="M/S2")
    angular_accel: float | None = setting(None, "angular acceleration limit, rad/s^2 (default off)", metavar="RAD/S2")
    max_command_hz: float = setting(
        500.0, "cap on velocity commands per second to the robot; a flood is coalesced to the latest", metavar="HZ"
    )
    position_moves: bool = setting(
        False,
        "let <prefix>/wheels/move drive the wheels by the robot's own SET_LR_WHEEL_POSITION; only for a robot known to "
        "support it as docs/safety.md 'Position moves' says (the simulator does)",
    )
    position_speed: float = setting(
        0.3, "rim speed at which the robot runs a position move, m/s (the simulator's 0.3): a move's time limit follows", metavar="M/S"
    )
    prefix: str = setting(DEFAULT_PREFIX, "key-expression prefix, e.g. fleet/a")
    reply_timeout: float = setting(0.5, "a request unanswered this long is given up (the original driver used 0.2 s)", metavar="S")
    silence_timeout: float = setting(1.0, "the control link is re-opened when requests go unanswered this long", metavar="S")
    log_silence_timeout: float = setting(
        3.5, "the log link is re-opened after this long without a report (the robot sends ~1 Hz)", metavar="S"
    )
    connect_timeout: float = setting(1.0, "TCP connect timeout to the robot", metavar="S")
    health_period: float = setting(1.0, "seconds between health reports", metavar="S")
    source: list[str] = setting(
        help="a command source NAME:PRIORITY[:TIMEOUT] on <prefix>/cmd_vel/NAME ('default' is plain cmd_vel); "
        "repeat for each; given at all, it replaces the defaults",
        factory=lambda: [f"{spec.name}:{spec.priority}:{spec.timeout:g}" for spec in DEFAULT_SOURCES],
        metavar="NAME:PRIO[:S]",
    )
    lock: list[str] = setting(
        help="a lock NAME:PRIORITY[:TIMEOUT] on <prefix>/lock/NAME: engaged, it blocks sources of that priority and below; "
        "with a timeout it is also engaged until refreshed within it (a heartbeat); repeat for each",
        factory=list,
        metavar="NAME:PRIO[:S]",
    )
    state_dir: str = setting(
        "",
        "where the e-stop latch is kept so that a crash, a restart or a reboot does not release it (default: systemd's "
        "$STATE_DIRECTORY, else $XDG_STATE_HOME/blackmetal, else ~/.local/state/blackmetal)",
        metavar="DIR",
    )
    unsafe_release_on_estop: bool = setting(
        False,
        "UNSAFE: let a release put on <prefix>/estop release the e-stop, which any user who may engage it may put; "
        "by default only <prefix>/estop/release releases (a right a router can give to a safety role alone)",
    )
    unsafe_start_released: bool = setting(
        False,
        "UNSAFE for a real robot: with no saved e-stop state (a first start, or a lost file) start released instead of "
        "engaged; blackmetal up sets it for the simulated robots it starts (a corrupt or unreadable state still engages)",
    )
    release_key_only: bool = setting(
        True,
        "kept for settings written before it was the default: only <prefix>/estop/release releases either way "
        "(see --unsafe-release-on-estop)",
    )
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)

    def check(self) -> None:
        """Refuse settings that cannot work, naming the setting."""
        check_positive(
            self,
            "poll_hz wheel_separation max_wheel_speed keepalive reply_timeout silence_timeout log_silence_timeout "
            "connect_timeout health_period max_command_hz linear_accel angular_accel impulses_left impulses_right position_speed",
        )
        for name, nominal in (("impulses_left", model.IMPULSES_PER_METER_LEFT), ("impulses_right", model.IMPULSES_PER_METER_RIGHT)):
            value = getattr(self, name)
            if not 0.5 * nominal <= value <= 2.0 * nominal:
                raise ConfigError(f"{name} {value} is not within half to twice the nominal {nominal:g}: is the calibration right?")
        if self.poll_hz > 1000:
            raise ConfigError(f"poll_hz {self.poll_hz} is beyond 1000 Hz")
        if self.max_wheel_speed > 1.0:
            raise ConfigError(f"max_wheel_speed {self.max_wheel_speed} is beyond the robot's wire limit of 1.0 m/s")
        if self.position_speed > 1.0:
            raise ConfigError(f"position_speed {self.position_speed} is beyond the robot's wire limit of 1.0 m/s")
        if self.position_moves and self.position_speed > self.max_wheel_speed:
            raise ConfigError(
                f"position_moves with position_speed {self.position_speed:g} m/s above max_wheel_speed {self.max_wheel_speed:g} m/s: "
                "every position move would be refused"
            )
        if self.keepalive >= model.ROBOT_WATCHDOG_S:
            raise ConfigError(f"keepalive {self.keepalive} s must be shorter than the robot's {model.ROBOT_WATCHDOG_S:g} s watchdog")
        if self.cmd_timeout < 0:
            raise ConfigError("cmd_timeout must be >= 0 (0 disables it)")
        for name, limit, why in TIME_LIMITS:
            if getattr(self, name) > limit:
                raise ConfigError(f"{name} {getattr(self, name):g} s is beyond {limit:g} s: {why}")
        for name in ("control_port", "log_port"):
            if not 1 <= getattr(self, name) <= 65535:
                raise ConfigError(f"{name} must be a TCP port 1-65535")
        validate_prefix(self.prefix)
        self.arbiter()

    def latch_store(self) -> FileLatchStore:
        """Where this robot's e-stop latch is kept (``state_dir``, else the default)."""
        return FileLatchStore(latch_path(self.state_dir or default_state_dir(), self.prefix), self.prefix)

    def arbiter(self) -> Arbiter:
        return arbiter_of(self.source, self.lock)

    def safety(self) -> SafetySettings:
        """The governor's settings: the ones of the same name, and each wheel's gain from its calibration."""
        same = {name: getattr(self, name) for name in SAFETY_SETTINGS}
        gain = model.WheelGain(
            left=self.impulses_left / model.IMPULSES_PER_METER_LEFT, right=self.impulses_right / model.IMPULSES_PER_METER_RIGHT
        )
        return SafetySettings(**same, wheel_gain=gain)
