"""The ``blackmetal`` command: one entry point, one subcommand per tool or service."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _schema(args: argparse.Namespace) -> int:
    from schemas import json_schemas

    schemas = json_schemas()
    if args.output is None:
        json.dump(schemas, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    folder = Path(args.output)
    folder.mkdir(parents=True, exist_ok=True)
    for name, schema in schemas.items():
        (folder / f"{name}.schema.json").write_text(json.dumps(schema, indent=2) + "\n")
    print(f"wrote {len(schemas)} schemas to {folder}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from . import main as gateway_main
    from .sim import main as sim_main

    parser = argparse.ArgumentParser(
        prog="blackmetal", description="Zenoh gateway, odometry and simulator for the Black Metal robot."
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    sim = sub.add_parser("sim", help="run the simulated robot (real wire protocol on TCP)", description=sim_main.__doc__)
    sim_main.build_parser(sim)
    sim.set_defaults(func=sim_main.run)
    gateway = sub.add_parser("gateway", help="run the gateway (robot link, safety, Zenoh)", description=gateway_main.__doc__)
    gateway_main.build_parser(gateway)
    gateway.set_defaults(func=gateway_main.run)
    from odometry_service import main as odometry_main
    from odometry_service import replay

    odometry = sub.add_parser("odometry", help="run the odometry service (impulses -> pose)", description=odometry_main.__doc__)
    odometry_main.build_parser(odometry)
    odometry.set_defaults(func=odometry_main.run)
    replay_parser = sub.add_parser("replay", help="replay a recorded impulse log through the odometry", description=replay.__doc__)
    replay.build_parser(replay_parser)
    replay_parser.set_defaults(func=replay.run)
    from . import up

    up_parser = sub.add_parser("up", help="run the demo: simulator, gateway and odometry in one command", description=up.__doc__)
    up.build_parser(up_parser)
    up_parser.set_defaults(func=up.run)
    from . import square, teleop, watch

    for name, module, text in (
        ("teleop", teleop, "drive from the keyboard"),
        ("watch", watch, "live view of pose, status, health and errors"),
        ("square", square, "drive a square and report the odometry's closure error"),
    ):
        tool = sub.add_parser(name, help=text, description=module.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
        module.build_parser(tool)
        tool.set_defaults(func=module.run)
    from . import bench, robots, router

    for name, module, text in (
        ("router", router, "run a Zenoh router from the Python wheel"),
        ("robots", robots, "list the robots whose gateway is alive"),
    ):
        tool = sub.add_parser(name, help=text, description=module.__doc__)
        module.build_parser(tool)
        tool.set_defaults(func=module.run)

    bench_parser = sub.add_parser("bench", help="measure latency, poll rate, replay speed, memory", description=bench.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    bench.build_parser(bench_parser)
    bench_parser.set_defaults(func=bench.run)
    schema = sub.add_parser("schema", help="print or write the JSON Schema of every message")
    schema.add_argument("-o", "--output", metavar="DIR", help="write one <Name>.schema.json per message into DIR")
    schema.set_defaults(func=_schema)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
