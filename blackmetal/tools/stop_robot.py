"""``blackmetal stop-robot --robot HOST``: leave the robot standing when its gateway is gone.

Connects to the robot's control port (the robot takes a new control
connection in place of a dead one), sends zero velocity and NORMAL_STOP, and
waits until the robot has accepted both, re-sending what it answers
FULL_BUFFER (or leaves unanswered) after a growing pause. ``blackmetal up``
runs it when its gateway dies; the systemd unit runs it as ``ExecStopPost``.
Exit 0 once the robot accepted the stop, 1 if it could not be reached or
did not accept within ``--timeout``.
"""

from __future__ import annotations

import argparse
import socket
import time

from blackmetal import robot_model as model
from blackmetal import wire
from blackmetal.runtime.settings import read_settings_file
from blackmetal.wire import CommandCode, StatusReply

from .client import ToolError, tool

#: Pause before re-sending a command the robot did not take: doubling from 5 ms, at most 250 ms.
RETRY_FIRST_S = 0.005
RETRY_CAP_S = 0.25


def stop_robot(host: str, port: int, timeout: float = 3.0) -> str | None:
    """Zero velocity, then NORMAL_STOP, each until accepted. None on success, else why not (one sentence)."""
    deadline = time.monotonic() + timeout
    try:
        sock = socket.create_connection((host, port), timeout=min(timeout, 1.0))
    except OSError as exc:
        return f"cannot connect to the robot's control port {host}:{port}: {exc.strerror or exc}"
    with sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        decoder = wire.ReplyDecoder()
        for request in (wire.set_velocity(left=0.0, right=0.0), wire.simple(CommandCode.NORMAL_STOP)):
            pause = RETRY_FIRST_S
            while True:
                if time.monotonic() >= deadline:
                    return f"the robot at {host}:{port} did not accept {request.command.name} within {timeout:g} s"
                try:
                    sock.sendall(wire.encode_request(request))
                except OSError as exc:
                    return f"lost the robot's control port {host}:{port}: {exc.strerror or exc}"
                if (status := _status_reply(sock, decoder, min(deadline, time.monotonic() + 0.5))) is not None and status.ok:
                    break
                time.sleep(pause)
                pause = min(pause * 2, RETRY_CAP_S)
    return None


def _status_reply(sock: socket.socket, decoder: wire.ReplyDecoder, until: float) -> StatusReply | None:
    """The next status reply, or None if none came before ``until`` (or the robot closed)."""
    while (left := until - time.monotonic()) > 0:
        sock.settimeout(left)
        try:
            data = sock.recv(4096)
        except (TimeoutError, OSError):
            return None
        if not data:
            return None
        for item in decoder.feed(data):
            if isinstance(item, StatusReply):
                return item
    return None


def build_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", metavar="HOST", help="the robot's address (default: the settings file's, else 127.0.0.1)")
    parser.add_argument("--control-port", type=int, metavar="PORT", help=f"(default: the settings file's, else {model.CONTROL_PORT})")
    parser.add_argument("--settings", metavar="FILE", help="the gateway's settings file, for the robot's address and port")
    parser.add_argument("--timeout", type=float, default=3.0, metavar="S", help="give up after this long (default 3)")


@tool("stop-robot")
def run(args: argparse.Namespace) -> int:
    found = read_settings_file(args.settings) if args.settings else {}  # a ConfigError: exit 2
    args.robot = args.robot or str(found.get("robot", "127.0.0.1"))
    args.control_port = args.control_port or int(found.get("control_port", model.CONTROL_PORT))
    if (reason := stop_robot(args.robot, args.control_port, args.timeout)) is not None:
        raise ToolError(reason)
    print(f"blackmetal stop-robot: the robot at {args.robot}:{args.control_port} accepted zero velocity and NORMAL_STOP")
    return 0
