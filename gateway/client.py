"""What every user tool needs: a Zenoh session with sensible defaults, latest values, clear failures.

Tools (teleop, watch, square) default to the demo's endpoint
``tcp/127.0.0.1:7447`` when no Zenoh flag is given, and fail with a message
that says what to check, not a traceback, when nothing answers.
"""

from __future__ import annotations

import argparse
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

import msgspec
import zenoh

from schemas import GatewayHealth, PayloadError, Pose, decode, to_bytes
from schemas import robot as facts

from .errors import GatewayError
from .zenoh_config import ZenohSettings, add_zenoh_arguments, validate_prefix, zenoh_settings

DEMO_ENDPOINT = "tcp/127.0.0.1:7447"
T = TypeVar("T", bound=msgspec.Struct)


class ToolError(GatewayError):
    """A user tool cannot do its job; the message says what to check."""


def add_client_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--prefix", default=facts.DEFAULT_PREFIX, help="key-expression prefix (default robot)")
    parser.add_argument("--wait", type=float, default=5.0, help="seconds to wait for the robot's services (default 5)")
    add_zenoh_arguments(parser)


def client_settings(args: argparse.Namespace) -> ZenohSettings:
    """The Zenoh flags, or the demo's endpoint (multicast scouting off) when none was given."""
    settings = zenoh_settings(args)
    if not settings.given:
        settings.connect = [DEMO_ENDPOINT]
        settings.no_multicast_scouting = True
    if settings.mode is None and not settings.listen:
        settings.listen = ["tcp/127.0.0.1:0"]  # a client peer needs no listener reachable from the LAN
    validate_prefix(args.prefix)
    return settings


def where(settings: ZenohSettings) -> str:
    return ", ".join(settings.connect) or ("multicast scouting" if not settings.no_multicast_scouting else "no endpoint")


class Latest:
    """Keeps the newest value of a key, decoded; the callback only stores it."""

    def __init__(self, session: zenoh.Session, key: str, message_type: type[T]) -> None:
        self.key = key
        self.message_type = message_type
        self.value: Any = None
        self.count = 0
        self.received_at = 0.0
        self._event = threading.Event()
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            self.value = decode(self.message_type, to_bytes(sample.payload))
        except PayloadError:
            return
        self.count += 1
        self.received_at = time.monotonic()
        self._event.set()

    def wait(self, timeout: float) -> Any:
        self._event.wait(timeout)
        return self.value

    def age(self) -> float:
        return time.monotonic() - self.received_at if self.count else float("inf")

    def close(self) -> None:
        self._sub.undeclare()


def query(session: zenoh.Session, key: str, message_type: type[T], timeout: float = 2.0, payload: bytes | None = None) -> T | None:
    """The first valid answer to a ``get`` on ``key``, or None."""
    for reply in session.get(key, payload=payload, timeout=timeout):
        if reply.ok is not None:
            try:
                return decode(message_type, to_bytes(reply.ok.payload))
            except PayloadError:
                continue
    return None


def wait_for_answer(fetch: Callable[[], T | None], timeout: float) -> T | None:
    deadline = time.monotonic() + timeout
    while True:
        value = fetch()
        if value is not None or time.monotonic() > deadline:
            return value
        time.sleep(0.2)


def require_gateway(session: zenoh.Session, prefix: str, settings: ZenohSettings, timeout: float) -> GatewayHealth:
    health = wait_for_answer(lambda: query(session, f"{prefix}/gateway/health", GatewayHealth, timeout=1.0), timeout)
    if health is None:
        raise ToolError(
            f"no gateway answered on {prefix}/gateway/health within {timeout:g} s (Zenoh: {where(settings)}). "
            "Is `blackmetal up` (or a gateway) running, with the same --prefix and a reachable endpoint (-e)?"
        )
    return health


def require_pose(session: zenoh.Session, prefix: str, settings: ZenohSettings, timeout: float) -> Pose:
    pose = wait_for_answer(lambda: query(session, f"{prefix}/pose", Pose, timeout=1.0), timeout)
    if pose is None:
        raise ToolError(
            f"no odometry service answered on {prefix}/pose within {timeout:g} s (Zenoh: {where(settings)}). "
            "Is `blackmetal up` (or `blackmetal odometry`) running?"
        )
    return pose
