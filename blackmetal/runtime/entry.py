"""How a service process starts and ends: settings, an asyncio loop, SIGINT/SIGTERM, one sentence on failure."""

from __future__ import annotations

import argparse
import asyncio
import gc
import logging
import os
import sys
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from typing import Generic, TypeVar

from blackmetal.schemas import BlackmetalError, ZenohUnavailable

from .fleet import FleetRobot, load_fleet, refuse_single_robot_options
from .settings import add_setting_arguments, load_settings
from .signals import loop_stop_on_signals
from .zenoh_setup import add_zenoh_arguments

T = TypeVar("T")
S = TypeVar("S")  # a service's settings


def run_service(name: str, load: Callable[[], T], serve: Callable[[T, asyncio.Event], Awaitable[None]]) -> int:
    """Load settings, then ``serve(settings, stop)`` until SIGINT/SIGTERM sets ``stop``.

    Exits 0 after a requested stop, 2 for settings it cannot use, 1 when the operating system refuses (a port in use);
    every failure is one line on stderr.
    """
    logging.basicConfig(level=logging.INFO, format=f"%(asctime)s {name} %(levelname)s %(message)s")

    async def _main(settings: T) -> None:
        await serve(settings, loop_stop_on_signals())

    try:
        with asyncio.Runner(loop_factory=loop_factory()) as runner:
            runner.run(_main(load()))
    except asyncio.CancelledError:
        pass  # stopped while it still waited for its router or hub (open_service_session): a requested stop
    except (BlackmetalError, OSError) as exc:
        print(f"blackmetal {name}: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, BlackmetalError) and not isinstance(exc, ZenohUnavailable) else 1
    logging.getLogger(f"blackmetal.{name}").info("stopped")
    return 0


@dataclass(frozen=True)
class Fleet(Generic[S]):
    """What ``--fleet FILE`` means to a service: every robot of the file in this one process."""

    #: The option's help.
    help: str
    #: Each robot's settings from the command line's (one sentence naming the robot for a mistake).
    settings: Callable[[S, list[FleetRobot]], list[S]]
    serve: Callable[[S, list[FleetRobot], asyncio.Event], Awaitable[None]]
    #: Settings that name one robot (name -> why), refused with --fleet.
    single_robot: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class ServiceCommand(Generic[S]):
    """A service's command, declared: its settings, how it serves one robot, and its fleet; gives ``build_parser``, ``run``, ``main``."""

    name: str
    settings: type[S]
    doc: str | None
    serve: Callable[[S, asyncio.Event], Awaitable[None]]
    fleet: Fleet[S] | None = None
    #: The interpreter's switch interval (s) for this process, when the service needs another than Python's.
    switch_interval: float | None = None

    def build_parser(self, parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
        parser = service_parser(f"blackmetal {self.name}", self.doc, self.settings, parser)
        if self.fleet is not None:
            parser.add_argument("--fleet", metavar="FILE", help=self.fleet.help)
        return parser

    def run(self, args: argparse.Namespace) -> int:
        """:func:`run_service` for one robot, or with ``--fleet FILE`` for every robot of the file: settings naming one
        robot are refused, and every robot's checked before the service opens Zenoh or a port."""
        if self.switch_interval is not None:
            sys.setswitchinterval(self.switch_interval)
        fleet = self.fleet
        if fleet is None or not getattr(args, "fleet", None):
            return run_service(self.name, lambda: load_settings(self.settings, args), self.serve)

        def load_fleet_settings() -> tuple[S, list[FleetRobot]]:
            base = load_settings(self.settings, args)
            refuse_single_robot_options(vars(args), base, fleet.single_robot)
            robots = load_fleet(args.fleet)
            fleet.settings(base, robots)
            return base, robots

        return run_service(self.name, load_fleet_settings, lambda loaded, stop: fleet.serve(*loaded, stop))

    def main(self, argv: list[str] | None = None) -> int:
        return self.run(self.build_parser().parse_args(argv))


def say(*lines: str | None) -> None:
    """What a service tells its user as it starts, each line flushed at once (a harness or a pipe reads it live); None
    lines are left out."""
    for line in lines:
        if line is not None:
            print(line, flush=True)


def freeze_start_up() -> None:
    """Once a service has built what it keeps: frozen, a full collection walks only what the command path allocates, not
    100k objects of start-up."""
    gc.freeze()


def loop_factory() -> Callable[[], asyncio.AbstractEventLoop] | None:
    """uvloop's event loop where it is installed, else the standard one (None; ``BLACKMETAL_EVENT_LOOP=asyncio``).

    Every sample wakes the loop from Zenoh's thread: 23 us with uvloop against 72 us, twice per command.
    """
    if os.environ.get("BLACKMETAL_EVENT_LOOP", "").lower() == "asyncio":
        return None
    try:
        import uvloop
    except ImportError:
        return None
    return uvloop.new_event_loop


def service_parser(
    prog: str, doc: str | None, settings_cls: type, parser: argparse.ArgumentParser | None = None
) -> argparse.ArgumentParser:
    """A service's options: one per settings field, then the shared Zenoh flags."""
    parser = parser or argparse.ArgumentParser(prog=prog, description=doc)
    add_setting_arguments(parser, settings_cls)
    add_zenoh_arguments(parser)
    return parser
