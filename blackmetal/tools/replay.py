"""``blackmetal replay FILE``: a recorded impulse log through the odometry pipeline in one numpy pass.

FILE is an MCAP recording (``blackmetal record``, ``blackmetal square
--record``) or JSON lines of WheelImpulses exactly as published on
``<prefix>/wheels/impulses``. The last line of stdout is the final pose as
one JSON object; ``-o FILE`` writes every pose as JSON lines; ``--compare``
sets the replay against the live poses a recording holds;
``--export-jsonl FILE`` writes a recording's impulses as JSON lines.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path

import msgspec
import numpy as np

from blackmetal.odometry_service.batch import BatchResult
from blackmetal.odometry_service.replay import final_pose, read_log, summary, write_poses
from blackmetal.odometry_service.settings import PipelineSettings
from blackmetal.recording.reader import is_mcap, topic_lines
from blackmetal.runtime.settings import add_setting_arguments, load_settings
from blackmetal.schemas import KEY_SPECS, BlackmetalError, ConfigError, Pose, encode

_SUFFIX = {spec.name: spec.suffix for spec in KEY_SPECS}


def key_matcher(prefix: str | None, name: str) -> Callable[[str], bool]:
    """Matches the recording's channel of key ``name`` (``impulses``): under ``prefix`` if given, else under any prefix."""
    suffix = _SUFFIX[name]
    if prefix:
        return lambda topic: topic == f"{prefix}/{suffix}"
    return lambda topic: topic.endswith("/" + suffix)


def load_impulses(path: str, prefix: str | None) -> tuple[bytes, str | None]:
    """The impulses as JSON lines, from an MCAP recording or a JSON-lines file; and what a cut-off recording lacked."""
    if is_mcap(path):
        return topic_lines(path, key_matcher(prefix, "impulses"))
    try:
        return Path(path).read_bytes(), None
    except OSError as exc:
        raise ConfigError(f"cannot read {path}: {exc.strerror}") from None


def compare(result: BatchResult, path: str, prefix: str | None) -> str:
    """The largest difference between the live poses recorded and the replayed poses of the same stamps."""
    text, _ = topic_lines(path, key_matcher(prefix, "pose"))
    live = msgspec.json.Decoder(Pose).decode_lines(text) if text.strip() else []
    if not live:
        return f"--compare: {path} holds no poses to compare with"
    return compare_poses(result.stamp, result.x, result.y, result.yaw, live)


def compare_poses(stamp: np.ndarray, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, live: list[Pose]) -> str:
    """Replayed poses against live ones of the same stamps, as motion from the first stamp they share: a replay
    starts at (0, 0, 0) while the live odometry may have run (or been reset) before the recording began."""
    index = {float(s): k for k, s in enumerate(stamp)}
    pairs = [(pose, index[pose.stamp]) for pose in live if pose.stamp in index]
    if not pairs:
        return f"--compare: none of the {len(live)} live poses has the stamp of a replayed one"
    start, k0 = pairs[0]
    turn = start.yaw - float(yaw[k0])
    c, s = math.cos(turn), math.sin(turn)
    ks = np.array([k for _, k in pairs])
    dx, dy = x[ks] - x[k0], y[ks] - y[k0]
    ax, ay = start.x + c * dx - s * dy, start.y + s * dx + c * dy
    dist = np.hypot(np.array([p.x for p, _ in pairs]) - ax, np.array([p.y for p, _ in pairs]) - ay)
    dyaw = np.abs(np.remainder(np.array([p.yaw for p, _ in pairs]) - (yaw[ks] + turn) + math.pi, math.tau) - math.pi)
    worst = int(np.argmax(dist))
    return (
        f"--compare: {len(pairs)} of {len(live)} live poses matched by stamp, compared as motion from the first "
        f"(live pose there x {start.x:.3f} m, y {start.y:.3f} m, yaw {start.yaw:.3f} rad); largest difference "
        f"{1e3 * dist.max():.3f} mm (at stamp {pairs[worst][0].stamp:.3f}), {1e3 * dyaw.max():.3f} mrad"
    )


def run(args: argparse.Namespace) -> int:
    try:
        settings = load_settings(PipelineSettings, args)
        data, truncated = load_impulses(args.file, args.prefix)
        if args.export_jsonl:
            lines = [line.strip() for line in data.splitlines() if line.strip()]
            Path(args.export_jsonl).write_bytes(b"".join(line + b"\n" for line in lines))
        result = read_log(data).replay(settings.params())
        comparison = compare(result, args.file, args.prefix) if args.compare and is_mcap(args.file) else None
    except (BlackmetalError, OSError) as exc:  # a file it cannot read is a ConfigError; one it cannot write, an OSError
        why = f"cannot write {exc.filename}: {exc.strerror}" if isinstance(exc, OSError) else exc
        print(f"blackmetal replay: {why}", file=sys.stderr)
        return 2
    if not len(result):
        print(f"blackmetal replay: {args.file} holds no usable impulse sample: nothing to replay", file=sys.stderr)
        return 2
    if args.output:
        with open(args.output, "wb") as out:
            write_poses(result, out)
    if not args.quiet:
        if truncated:
            print(
                f"note: the recording ends early (its recorder was stopped abruptly), {truncated}; every whole sample before "
                f"the cut was replayed, the last at stamp {final_pose(result).stamp:.3f}",
                file=sys.stderr,
            )
        print(summary(result), file=sys.stderr)
        for reason in result.rejected[:5]:
            print(f"rejected: {reason}", file=sys.stderr)
        for event in result.events[:5]:
            print(f"note: {event}", file=sys.stderr)
    if args.compare:
        print(comparison or "--compare needs an MCAP recording that holds the live poses", file=sys.stderr)
    sys.stdout.buffer.write(encode(final_pose(result)) + b"\n")
    sys.stdout.flush()
    return 0


def build_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="MCAP recording, or JSON-lines file of WheelImpulses")
    parser.add_argument("-o", "--output", metavar="FILE", help="write every pose as JSON lines")
    parser.add_argument("-q", "--quiet", action="store_true", help="no summary on stderr")
    parser.add_argument("--prefix", help="in a recording, the robot's prefix (default: the one impulses channel it holds)")
    parser.add_argument("--compare", action="store_true", help="print the largest difference from the live poses of the recording")
    parser.add_argument("--export-jsonl", metavar="FILE", help="also write the impulses as JSON lines")
    add_setting_arguments(parser, PipelineSettings)
