"""``blackmetal sim``: the simulated robot on real TCP ports, optionally on Zenoh (truth out, faults in)."""

from __future__ import annotations

import argparse
import asyncio
import time
from contextlib import ExitStack
from dataclasses import dataclass, field

import msgspec

from blackmetal import robot_model as model
from blackmetal.runtime.entry import run_service, service_parser
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.settings import check_positive, load_settings, setting
from blackmetal.runtime.zenoh_setup import ZenohSettings, open_service_session
from schemas import DEFAULT_PREFIX, ConfigError, Keys, SimFaults, validate_prefix

from .physics import RobotParams, SimRobot
from .server import SimServer

FAULTS = tuple(SimFaults.__struct_fields__)


@dataclass(slots=True)
class SimSettings:
    host: str = setting("127.0.0.1", "address to listen on", metavar="HOST")
    control_port: int = setting(model.CONTROL_PORT, "control port; 0 = a free port", metavar="PORT")
    log_port: int = setting(model.LOG_PORT, "log port; 0 = a free port", metavar="PORT")
    log_interval: float = setting(1.0, "seconds between log-port state reports", metavar="S")
    wheel_separation: float = setting(model.WHEEL_SEPARATION, "the true distance between the wheels, m", metavar="M")
    left_wheel_scale: float = setting(
        1.0, "real travel of the left wheel per reported impulse, relative to the nominal constant", metavar="F"
    )
    right_wheel_scale: float = setting(1.0, "the same for the right wheel", metavar="F")
    accel_limit: float | None = setting(None, "motor acceleration limit, m/s^2 (default none)", metavar="M/S2")
    watchdog: float = setting(model.ROBOT_WATCHDOG_S, "stop after this many seconds without a motion command", metavar="S")
    seed: int | None = setting(None, "random seed for faults", metavar="N")
    truth_hz: float = setting(50.0, "rate of <prefix>/sim/truth", metavar="HZ")
    prefix: str | None = setting(None, f"key prefix (default {DEFAULT_PREFIX}); implies Zenoh")
    use_zenoh: bool = setting(False, "publish the truth on Zenoh with default settings", flag="--zenoh")
    dropout: float = setting(0.0, "fault: per-wheel probability of a stray 0 reading", metavar="P")
    spike: float = setting(0.0, "fault: per-wheel probability of an impossible reading", metavar="P")
    full_buffer: float = setting(0.0, "fault: probability a command is dropped with FULL_BUFFER", metavar="P")
    delay: float = setting(0.0, "fault: delay before every reply, s", metavar="S")
    garbage: float = setting(0.0, "fault: probability of garbage bytes before a reply", metavar="P")
    glue: float = setting(0.0, "fault: probability a reply is glued to the next", metavar="P")
    split: float = setting(0.0, "fault: probability a reply is split across writes", metavar="P")
    disconnect: float = setting(0.0, "fault: probability per request of dropping the connection", metavar="P")
    silent: bool = setting(False, "fault: keep the connections open but never answer")
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)

    def check(self) -> None:
        check_positive(
            wheel_separation=self.wheel_separation,
            watchdog=self.watchdog,
            truth_hz=self.truth_hz,
            log_interval=self.log_interval,
            accel_limit=self.accel_limit,
            left_wheel_scale=self.left_wheel_scale,
            right_wheel_scale=self.right_wheel_scale,
        )
        for name in ("left_wheel_scale", "right_wheel_scale"):
            if not 0.5 <= getattr(self, name) <= 2.0:
                raise ConfigError(f"{name} must be within 0.5..2.0, got {getattr(self, name)}")
        if self.prefix is not None:
            validate_prefix(self.prefix)
        self.faults()

    def faults(self) -> SimFaults:
        try:
            return msgspec.convert({name: getattr(self, name) for name in FAULTS}, SimFaults)
        except msgspec.ValidationError as exc:
            raise ConfigError(f"invalid fault setting: {exc}") from None

    @property
    def uses_zenoh(self) -> bool:
        return self.zenoh.given or self.use_zenoh or self.prefix is not None


async def serve(settings: SimSettings, stop: asyncio.Event) -> None:
    """Serve until ``stop`` is set; then close everything within a second or two."""
    params = RobotParams.with_wheel_scales(
        left=settings.left_wheel_scale,
        right=settings.right_wheel_scale,
        wheel_separation=settings.wheel_separation,
        accel_limit=settings.accel_limit,
        watchdog=settings.watchdog,
    )
    robot = SimRobot(params, now=time.monotonic(), seed=settings.seed)
    robot.faults = settings.faults()
    server = SimServer(robot, settings.host, settings.control_port, settings.log_port, log_interval=settings.log_interval)
    await server.start()
    keys = Keys(settings.prefix or DEFAULT_PREFIX)
    with ExitStack() as stack:
        edge = None
        if settings.uses_zenoh:
            from .zenoh_edge import SimZenoh

            session = stack.enter_context(await open_service_session(settings.zenoh, stop, "sim"))
            edge = SimZenoh(session, keys, robot, server.clock)
            stack.callback(edge.close)
            edge.attach(asyncio.get_running_loop())
        print(
            f"blackmetal sim ready: control {settings.host}:{server.control_port}, log {settings.host}:{server.log_port}"
            + (f", truth on {keys.sim_truth}" if edge is not None else ""),
            flush=True,
        )
        announce_ready("sim", host=settings.host, control_port=server.control_port, log_port=server.log_port)
        period = 1.0 / settings.truth_hz
        next_tick = time.monotonic()
        try:
            while not stop.is_set():
                if edge is not None:
                    edge.tick()  # the truth, and error summaries when due
                else:
                    robot.advance(server.clock())
                next_tick += period
                delay = next_tick - time.monotonic()
                if delay < -period:  # fell behind (loaded machine): do not burst to catch up
                    next_tick = time.monotonic()
                    delay = 0.0
                try:
                    await asyncio.wait_for(stop.wait(), timeout=max(delay, 0.0))
                except TimeoutError:
                    pass
        finally:
            await server.close()


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = service_parser("blackmetal sim", __doc__, SimSettings, parser)
    fleet = parser.add_mutually_exclusive_group()
    fleet.add_argument("--robots", type=int, metavar="N", help="simulate N robots r1..rN under fleet/<id>, each on free ports")
    fleet.add_argument("--fleet", metavar="FILE", help="simulate the robots of this fleet file, each on its ports")
    parser.add_argument("--write-fleet", metavar="FILE", help="with --robots or --fleet: write the fleet file with the bound ports")
    return parser


def run(args: argparse.Namespace) -> int:
    robots = getattr(args, "robots", None)
    fleet = getattr(args, "fleet", None)
    if robots is not None or fleet:
        from blackmetal.runtime.fleet import FleetRobot, load_fleet, numbered_fleet

        from .fleet import serve_fleet

        def load_fleet_settings() -> tuple[SimSettings, list[FleetRobot]]:
            base = load_settings(SimSettings, args)
            members = load_fleet(fleet) if fleet else numbered_fleet(int(robots or 0), host=base.host)
            return base, members

        return run_service("sim", load_fleet_settings, lambda loaded, stop: serve_fleet(*loaded, stop, args.write_fleet))
    return run_service("sim", lambda: load_settings(SimSettings, args), serve)


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))
