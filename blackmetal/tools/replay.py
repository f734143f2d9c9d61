"""``blackmetal replay FILE``: a recorded impulse log through the odometry pipeline in one numpy pass.

The file holds JSON lines of WheelImpulses, exactly as published on
``<prefix>/wheels/impulses``. The last line of stdout is the final pose as
one JSON object; ``-o FILE`` writes every pose as JSON lines.
"""

from __future__ import annotations

import argparse
import sys

from blackmetal.runtime.settings import add_setting_arguments, load_settings
from odometry_service.replay import final_pose, replay_file, summary, write_poses
from odometry_service.settings import PipelineSettings
from schemas import BlackmetalError, encode


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    parser = parser or argparse.ArgumentParser(prog="blackmetal replay", description=__doc__)
    parser.add_argument("file", help="JSON-lines file of WheelImpulses")
    parser.add_argument("-o", "--output", metavar="FILE", help="write every pose as JSON lines")
    parser.add_argument("-q", "--quiet", action="store_true", help="no summary on stderr")
    add_setting_arguments(parser, PipelineSettings)
    return parser


def run(args: argparse.Namespace) -> int:
    try:
        settings = load_settings(PipelineSettings, args)
        result = replay_file(args.file, settings.params())
    except BlackmetalError as exc:
        print(f"blackmetal replay: {exc}", file=sys.stderr)
        return 2
    if not len(result):
        print(f"blackmetal replay: {args.file} holds no usable impulse sample: nothing to replay", file=sys.stderr)
        return 2
    if args.output:
        with open(args.output, "wb") as out:
            write_poses(result, out)
    if not args.quiet:
        print(summary(result), file=sys.stderr)
        for reason in result.rejected[:5]:
            print(f"rejected: {reason}", file=sys.stderr)
        for event in result.events[:5]:
            print(f"note: {event}", file=sys.stderr)
    sys.stdout.buffer.write(encode(final_pose(result)) + b"\n")
    sys.stdout.flush()
    return 0
