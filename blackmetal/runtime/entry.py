"""How a service process starts and ends: settings, an asyncio loop, SIGINT/SIGTERM, one sentence on failure."""

from __future__ import annotations

import argparse
import asyncio
import gc
import logging
import os
import sys
from collections.abc import Awaitable, Callable, Mapping
from typing import TypeVar

from blackmetal.schemas import BlackmetalError, ZenohUnavailable

from .fleet import FleetRobot, load_fleet, refuse_single_robot_options
from .settings import add_setting_arguments, load_settings
from .signals import loop_stop_on_signals
from .zenoh_setup import add_zenoh_arguments

T = TypeVar("T")
S = TypeVar("S")  # a service's settings


def run_service(name: str, load: Callable[[], T], serve: Callable[[T, asyncio.Event], Awaitable[None]]) -> int:
    """Load settings, then ``serve(settings, stop)`` until SIGINT/SIGTERM sets ``stop``.

    Exit codes: 0 after a requested stop (also while it still waited for its
    router or hub); 2 for a setting or configuration the service cannot use;
    1 when the operating system refuses (a port in use, an address not
    ours). Every failure is one line on stderr.
    """
    logging.basicConfig(level=logging.INFO, format=f"%(asctime)s {name} %(levelname)s %(message)s")

    async def _main(settings: T) -> None:
        await serve(settings, loop_stop_on_signals())

    try:
        with asyncio.Runner(loop_factory=loop_factory()) as runner:
            runner.run(_main(load()))
    except asyncio.CancelledError:
        pass  # stopped while it still waited for its router or hub (open_service_session): a requested stop
    except ZenohUnavailable as exc:
        print(f"blackmetal {name}: {exc}", file=sys.stderr)
        return 1
    except BlackmetalError as exc:
        print(f"blackmetal {name}: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"blackmetal {name}: {exc}", file=sys.stderr)
        return 1
    logging.getLogger(f"blackmetal.{name}").info("stopped")
    return 0


def run_single_or_fleet(
    name: str,
    args: argparse.Namespace,
    kind: type[S],
    serve: Callable[[S, asyncio.Event], Awaitable[None]],
    fleet_settings: Callable[[S, list[FleetRobot]], object],
    serve_fleet: Callable[[S, list[FleetRobot], asyncio.Event], Awaitable[None]],
    single_robot: Mapping[str, str] | None = None,
) -> int:
    """:func:`run_service` for one robot, or with ``--fleet FILE`` for every robot of the file in this process.

    With a fleet, the settings in ``single_robot`` (name -> why) are refused,
    and every robot's settings (``fleet_settings``) are checked before the
    service opens Zenoh or a port.
    """
    if not getattr(args, "fleet", None):
        return run_service(name, lambda: load_settings(kind, args), serve)

    def load_fleet_settings() -> tuple[S, list[FleetRobot]]:
        base = load_settings(kind, args)
        if single_robot:
            refuse_single_robot_options(vars(args), base, single_robot)
        robots = load_fleet(args.fleet)
        fleet_settings(base, robots)
        return base, robots

    return run_service(name, load_fleet_settings, lambda loaded, stop: serve_fleet(*loaded, stop))


def freeze_start_up() -> None:
    """Once per process, when a service has built what it keeps: out of the garbage collector's sight.

    Modules, Zenoh and the cores live as long as the process; frozen, a full
    collection walks only what the command path allocates, not 100k objects
    of start-up.
    """
    gc.freeze()


def loop_factory() -> Callable[[], asyncio.AbstractEventLoop] | None:
    """uvloop's event loop where it is installed (Linux, macOS), else the standard one (None).

    Every Zenoh sample a service handles wakes its loop from Zenoh's thread;
    uvloop's wake-up takes 23 us here against 72 us for the standard loop,
    and a command crosses two of them on its way to the robot.
    ``BLACKMETAL_EVENT_LOOP=asyncio`` selects the standard loop.
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
