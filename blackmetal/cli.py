"""The ``blackmetal`` command: one entry point, one subcommand per tool or service."""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
from pathlib import Path

from . import __version__
from .runtime.harness import end_with_parent


def _schema(args: argparse.Namespace) -> int:
    from blackmetal.schemas import json_schemas

    schemas = json_schemas()
    if args.output is None:
        print(json.dumps(schemas, indent=2))
        return 0
    folder = Path(args.output)
    folder.mkdir(parents=True, exist_ok=True)
    for name, schema in schemas.items():
        (folder / f"{name}.schema.json").write_text(json.dumps(schema, indent=2) + "\n")
    print(f"wrote {len(schemas)} schemas to {folder}")
    return 0


#: Subcommand -> (module with build_parser(parser) and run(args), one-line help).
COMMANDS: dict[str, tuple[str, str]] = {
    "sim": ("blackmetal.sim.main", "run the simulated robot (real wire protocol on TCP)"),
    "gateway": ("blackmetal.gateway.main", "run the gateway (robot link, safety, Zenoh)"),
    "odometry": ("blackmetal.odometry_service.main", "run the odometry service (impulses -> pose)"),
    "nav": ("blackmetal.nav.main", "run the navigation service (goals on nav/goal -> cmd_vel/nav)"),
    "ros2": ("blackmetal.ros2.main", "run the ROS 2 adapter: the robot as a ROS 2 node over rmw_zenoh or zenoh-bridge-ros2dds"),
    "foxglove": ("blackmetal.foxglove.main", "serve a live Foxglove view of the robot (WebSocket), optionally to MCAP"),
    "calibrate": ("blackmetal.tools.calibrate", "fit the odometry's constants from recordings (UMBmark or a trajectory fit)"),
    "record": ("blackmetal.tools.record", "record the robot's keys into an MCAP file"),
    "replay": ("blackmetal.tools.replay", "replay a recorded impulse log through the odometry"),
    "up": ("blackmetal.tools.up", "run the demo: simulator, gateway and odometry in one command"),
    "teleop": ("blackmetal.tools.teleop", "drive from the keyboard"),
    "watch": ("blackmetal.tools.watch", "live view of pose, status, health and errors"),
    "square": ("blackmetal.tools.square", "drive a square and report the odometry's closure error"),
    "router": ("blackmetal.tools.router", "run a Zenoh router from the Python wheel"),
    "robots": ("blackmetal.tools.list_robots", "list the robots whose gateway is alive"),
    "goto": ("blackmetal.tools.goto", "send the robot to X Y [YAW] and follow it there (Ctrl-C cancels)"),
    "estop": ("blackmetal.tools.estop", "engage or release the emergency stop, confirmed by the gateway"),
    "params": ("blackmetal.tools.params", "show the gateway's parameters, or set some on the running gateway"),
    "stop-robot": ("blackmetal.tools.stop_robot", "send the robot zero velocity and NORMAL_STOP (when its gateway is gone)"),
    "urdf": ("blackmetal.tools.urdf", "print the robot's URDF (for robot_state_publisher, RViz, Foxglove)"),
    "bench": ("blackmetal.bench", "measure latency, poll rate, replay speed, memory"),
}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The full command; with ``only``, just that subcommand's module is imported
    (so ``blackmetal sim`` without Zenoh flags never loads Zenoh)."""
    parser = argparse.ArgumentParser(prog="blackmetal", description="Zenoh gateway, odometry and simulator for the Black Metal robot.")
    parser.add_argument("--version", action="version", version=f"blackmetal {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module_name, text) in COMMANDS.items():
        if only is not None and name != only:
            sub.add_parser(name, help=text)
            continue
        module = importlib.import_module(module_name)
        description = (module.__doc__ or "").replace("``", "")  # the module docstring as help text, without reST's double backticks
        command = sub.add_parser(name, help=text, description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
        module.build_parser(command)
        command.set_defaults(func=module.run)
    schema = sub.add_parser("schema", help="print or write the JSON Schema of every message")
    schema.add_argument("-o", "--output", metavar="DIR", help="write one <Name>.schema.json per message into DIR")
    schema.set_defaults(func=_schema)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand; output piped into a reader that stops early (``| head``) ends quietly."""
    argv = sys.argv[1:] if argv is None else argv
    end_with_parent()
    try:
        parser = build_parser(argv[0] if argv and argv[0] in COMMANDS else None)
        args, unknown = parser.parse_known_args(argv)
        if unknown:  # the subcommand's usage says what it takes, not the top level's
            subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
            subparsers.choices[args.command].error(f"unrecognized arguments: {' '.join(unknown)}")
        return int(args.func(args))
    except BrokenPipeError:
        # the reader is gone: point stdout at nothing so the interpreter's final flush cannot fail again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
