"""``blackmetal teleop``: drive the robot from the keyboard.

Arrows or WASD drive, space stops, ``e`` toggles the emergency stop, ``+``/``-``
change the speed, ``q`` quits. While a key is held (the terminal repeats it)
a command goes out at 10 Hz on ``cmd_vel/teleop`` (the command source
``teleop``, priority 100: it overrides navigation); when it is released, one
zero command. The status line says which source drives. The terminal is
restored on any exit.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import select
import signal
import sys
import termios
import time
import tty
from dataclasses import dataclass

import zenoh

from blackmetal.schemas import EStop, GatewayHealth, Pose, Sources, Twist, Vector3, encode

from .client import Latest, add_client_arguments, add_drive_arguments, connect, require_gateway, tool

#: Key -> (forward, turn) direction.
DRIVE_KEYS: dict[str, tuple[float, float]] = {
    "w": (1.0, 0.0), "up": (1.0, 0.0),
    "s": (-1.0, 0.0), "down": (-1.0, 0.0),
    "a": (0.0, 1.0), "left": (0.0, 1.0),
    "d": (0.0, -1.0), "right": (0.0, -1.0),
}  # fmt: skip
#: Raw terminal input -> key name: arrows arrive as ESC [ A..D, Ctrl-C and Ctrl-D quit.
NAMES = {"\x1b[A": "up", "\x1b[B": "down", "\x1b[C": "right", "\x1b[D": "left", " ": "space", "\x03": "quit", "\x04": "quit"}


def parse_keys(data: bytes) -> list[str]:
    """Key names from raw terminal bytes."""
    text = data.decode("utf-8", errors="ignore")
    return [NAMES.get(key, key.lower()) for key in re.findall(r"\x1b\[[ABCD]|.", text, re.DOTALL)]


@dataclass
class Teleop:
    """Keyboard state to commands, clock injected; no I/O."""

    speed: float = 0.2
    turn_rate: float = 0.8
    hold: float = 0.7  # how long a key counts as held after its last repeat (s)
    rate: float = 10.0
    direction: tuple[float, float] = (0.0, 0.0)
    last_key_at: float = -math.inf
    last_sent_at: float = -math.inf
    moving: bool = False
    estop: bool = False
    quit: bool = False

    def on_key(self, key: str, now: float) -> list[tuple[str, object]]:
        """Handle one key; returns messages to publish now as (kind, message)."""
        out: list[tuple[str, object]] = []
        if key in DRIVE_KEYS:
            self.direction = DRIVE_KEYS[key]
            self.last_key_at = now
            if not self.moving or now - self.last_sent_at >= 1.0 / self.rate:
                out.append(("cmd_vel", self._twist()))
                self.last_sent_at = now
            self.moving = True
        elif key == "space":
            out.append(self._stop(now))
        elif key == "e":
            self.estop = not self.estop
            out.append(("estop" if self.estop else "estop_release", EStop(engaged=self.estop)))  # a release on its own key
            if self.moving:
                out.append(self._stop(now))
        elif key in ("+", "="):
            self.speed = min(self.speed * 1.25, 0.8)
            self.turn_rate = min(self.turn_rate * 1.25, 3.0)
        elif key in ("-", "_"):
            self.speed = max(self.speed / 1.25, 0.02)
            self.turn_rate = max(self.turn_rate / 1.25, 0.1)
        elif key in ("q", "quit"):
            self.quit = True
            if self.moving:
                out.append(self._stop(now))
        return out

    def tick(self, now: float) -> list[tuple[str, object]]:
        """Call often: repeats the command at ``rate`` while held, stops once on release."""
        if not self.moving:
            return []
        if now - self.last_key_at > self.hold:
            return [self._stop(now)]
        if now - self.last_sent_at >= 1.0 / self.rate:
            self.last_sent_at = now
            return [("cmd_vel", self._twist())]
        return []

    def _stop(self, now: float) -> tuple[str, object]:
        self.moving = False
        self.direction = (0.0, 0.0)
        self.last_sent_at = now
        return ("cmd_vel", Twist())

    def _twist(self) -> Twist:
        forward, turn = self.direction
        return Twist(linear=Vector3(x=forward * self.speed), angular=Vector3(z=turn * self.turn_rate))


def _status(teleop: Teleop, pose: Pose | None, health: GatewayHealth | None) -> str:
    forward, turn = teleop.direction
    parts = [f"cmd v={forward * teleop.speed:+.2f} w={turn * teleop.turn_rate:+.2f} (max {teleop.speed:.2f} m/s)"]
    if pose is not None:
        parts.append(f"pose x={pose.x:+.3f} y={pose.y:+.3f} yaw={math.degrees(pose.yaw):+6.1f}°")
    if health is not None:
        parts.append(f"link {health.control.state}")
        parts.append(f"driving: {health.active_source or 'nobody'}")
        parts.append("E-STOP ENGAGED: commands refused, e releases" if health.estop else "e-stop off")
    return " | ".join(parts)


@tool("teleop")
def run(args: argparse.Namespace) -> int:
    if not os.isatty(sys.stdin.fileno()):
        print("blackmetal teleop: needs a terminal (stdin is not a TTY)", file=sys.stderr)
        return 2
    keys, settings, session = connect(args)
    with session:
        health0 = require_gateway(session, keys, settings, args.wait)
        teleop = Teleop(speed=args.speed, turn_rate=args.turn_rate, hold=args.hold, estop=health0.estop)
        publishers = {
            "cmd_vel": session.declare_publisher(keys.cmd_vel_of(args.source), express=True),
            "estop": session.declare_publisher(keys.estop, express=True),
            "estop_release": session.declare_publisher(keys.estop_release, express=True),
        }
        pose = Latest(session, keys.pose, Pose)
        health = Latest(session, keys.health, GatewayHealth, health0)
        print(
            f"blackmetal teleop on {args.prefix} via {settings.where()}: arrows/WASD drive, space stop, e e-stop, +/- speed, q quit",
            flush=True,
        )
        return _loop(teleop, publishers, pose, health)


def _terminate(*_: object) -> None:
    raise SystemExit(0)  # unwinds through the finally that restores the terminal


def _loop(teleop: Teleop, publishers: dict[str, zenoh.Publisher], pose: Latest, health: Latest) -> int:
    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    previous_term = signal.signal(signal.SIGTERM, _terminate)
    try:
        tty.setcbreak(fd)
        last_draw = 0.0
        while not teleop.quit:
            ready, _, _ = select.select([fd], [], [], 0.05)
            now = time.monotonic()
            messages = []
            if ready:
                if not (data := os.read(fd, 64)):
                    break
                for key in parse_keys(data):
                    messages += teleop.on_key(key, now)
            messages += teleop.tick(now)
            for kind, message in messages:
                publishers[kind].put(encode(message))  # type: ignore[arg-type]
            if now - last_draw > 0.2 or messages:
                sys.stdout.write("\r\x1b[2K" + _status(teleop, pose.value, health.value))
                sys.stdout.flush()
                last_draw = now
    except KeyboardInterrupt:
        if teleop.moving:
            publishers["cmd_vel"].put(encode(Twist()))
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)
        signal.signal(signal.SIGTERM, previous_term)
        sys.stdout.write("\n")
        sys.stdout.flush()
    return 0


def build_parser(parser: argparse.ArgumentParser) -> None:
    add_drive_arguments(parser, turn_rate=0.8)
    parser.add_argument("--hold", type=float, default=0.7, help="a key counts as held this long after its last repeat, s")
    parser.add_argument(
        "--source", default=Sources.TELEOP, help="command source to publish as, on <prefix>/cmd_vel/SOURCE (default teleop, priority 100)"
    )
    add_client_arguments(parser)
