"""``blackmetal record``: the robot's keys into an MCAP file that Foxglove, the mcap CLI and PlotJuggler read.

Every key under the prefix by default (``-k`` chooses), one channel per key
with its message's JSON Schema, payloads byte for byte as received. Ctrl-C,
SIGTERM or ``--duration`` finish the file properly; chunks are closed every
second, so a recorder killed outright loses at most the last second.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from blackmetal.recording.writer import McapRecording, SessionRecorder
from blackmetal.runtime.harness import announce_ready
from blackmetal.runtime.signals import stop_on_signals
from blackmetal.schemas import ConfigError, require_extra

from .client import add_client_arguments, connect, tool


def default_name() -> str:
    return time.strftime("blackmetal-%Y%m%d-%H%M%S.mcap")


@tool("record")
def run(args: argparse.Namespace) -> int:
    require_extra("blackmetal record", "record", "mcap")
    if args.duration is not None and not args.duration > 0:
        raise ConfigError(f"--duration must be positive, got {args.duration}")
    if args.split_size is not None and not args.split_size > 0:
        raise ConfigError(f"--split-size must be positive (MB), got {args.split_size}")
    stop = stop_on_signals()
    keys, settings, session = connect(args, (stop, "record"))
    if session is None:
        return 0  # stopped while it waited for its router or hub
    path = Path(args.output or default_name())
    with session:
        keyexprs = args.key or [keys.everything]
        split = None if args.split_size is None else int(args.split_size * 1e6)
        recording = McapRecording(path, keys, split_bytes=split)
        recorder = SessionRecorder(session, keyexprs, recording)
        print(f"blackmetal record: {', '.join(keyexprs)} via {settings.where()} -> {path} (Ctrl-C to finish)", flush=True)
        announce_ready("record", file=str(path), keys=keyexprs)
        started = time.monotonic()
        deadline = started + args.duration if args.duration else None
        tty = sys.stdout.isatty()
        try:
            while not stop.wait(0.5):
                if tty:
                    sys.stdout.write("\r\x1b[2K" + recording.progress(time.monotonic() - started))
                    sys.stdout.flush()
                if deadline is not None and time.monotonic() >= deadline:
                    break
        finally:
            recorder.stop()
        if tty:
            print()
        if recorder.error is not None:
            raise ConfigError(f"the recording stopped early: {recorder.error}")
        counts = ", ".join(f"{k} {n}" for k, n in sorted(recording.stats.items())) or "no messages"
        files = ", ".join(str(f) for f in recording.files)
        print(f"blackmetal record: wrote {files} ({time.monotonic() - started:.1f} s; {counts})", flush=True)
    return 0


def build_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-o", "--output", metavar="FILE.mcap", help="the recording (default blackmetal-<date>-<time>.mcap)")
    parser.add_argument(
        "-k", "--key", action="append", metavar="KEYEXPR", help="record this key expression (repeatable; default <prefix>/**)"
    )
    parser.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds (default: until Ctrl-C)")
    parser.add_argument("--split-size", type=float, metavar="MB", help="start a new file (name-001.mcap, ...) after this many MB")
    add_client_arguments(parser)
