"""What every user tool needs: a Zenoh session, latest values, and failures that say what to check.

A tool fails at once when nothing answers; the recorder, a service, waits for its endpoint instead.
"""

from __future__ import annotations

import argparse
import functools
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any, TypeVar

import msgspec

from blackmetal.runtime.harness import ChildFailed
from blackmetal.runtime.zenoh_setup import ZenohSettings, add_zenoh_arguments, open_session, open_when_reachable, zenoh_settings
from blackmetal.schemas import DEFAULT_PREFIX, BlackmetalError, GatewayHealth, Keys, PayloadError, Pose, ZenohUnavailable, decode, to_bytes

if TYPE_CHECKING:
    import zenoh  # not at run time: the offline tools (replay, calibrate, stop-robot) never load it

T = TypeVar("T", bound=msgspec.Struct)


class ToolError(BlackmetalError):
    """A user tool cannot do its job; the message says what to check."""


def add_client_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--prefix", default=DEFAULT_PREFIX, help=f"key-expression prefix (default {DEFAULT_PREFIX})")
    parser.add_argument("--wait", type=float, default=5.0, help="seconds to wait for the robot's services (default 5)")
    add_zenoh_arguments(parser)


class Latest:
    """The newest decoded value of a key; the callback only stores it."""

    def __init__(self, session: zenoh.Session, key: str, message_type: type[T], value: Any = None) -> None:
        self.message_type = message_type
        self.value: Any = value
        self.count = 0
        self.received_at = 0.0
        self._event = threading.Event()
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if (value := decoded(self.message_type, sample)) is None:
            return
        self.value = value
        self.count += 1
        self.received_at = time.monotonic()
        self._event.set()

    def wait(self, timeout: float) -> Any:
        self._event.wait(timeout)
        return self.value

    def age(self) -> float:
        return time.monotonic() - self.received_at if self.count else float("inf")


def decoded(message_type: type[T], sample: zenoh.Sample) -> T | None:
    """The sample's message; None for a payload that does not decode, which every tool skips."""
    try:
        return decode(message_type, to_bytes(sample.payload))
    except PayloadError:
        return None


def decoded_replies(replies: Any, message_type: type[T]) -> Iterator[T]:
    """The answers among ``replies`` (a ``get``'s) that decode as ``message_type``."""
    for reply in replies:
        if reply.ok is not None and (value := decoded(message_type, reply.ok)) is not None:
            yield value


def first_reply(replies: Any, message_type: type[T]) -> T | None:
    return next(decoded_replies(replies, message_type), None)


def query(session: zenoh.Session, key: str, message_type: type[T], timeout: float = 2.0) -> T | None:
    """The first valid answer to a ``get`` on ``key``, or None."""
    return first_reply(session.get(key, timeout=timeout), message_type)


def _require(session: zenoh.Session, key: str, message_type: type[T], settings: ZenohSettings, timeout: float, who: str, hint: str) -> T:
    """The first valid answer on ``key`` within ``timeout`` (asked once a second), or ToolError: no ``who`` answered, ``hint``."""
    deadline = time.monotonic() + timeout
    while (value := query(session, key, message_type, timeout=1.0)) is None:
        if time.monotonic() > deadline:
            raise ToolError(f"no {who} answered on {key} within {timeout:g} s (Zenoh: {settings.where()}). {hint}")
        time.sleep(0.2)
    return value


def require_gateway(session: zenoh.Session, keys: Keys, settings: ZenohSettings, timeout: float) -> GatewayHealth:
    hint = "Is `blackmetal up` (or a gateway) running, with the same --prefix and a reachable endpoint (-e)?"
    return _require(session, keys.health, GatewayHealth, settings, timeout, "gateway", hint)


def require_pose(session: zenoh.Session, keys: Keys, settings: ZenohSettings, timeout: float) -> Pose:
    hint = "Is `blackmetal up` (or `blackmetal odometry`) running?"
    return _require(session, keys.pose, Pose, settings, timeout, "odometry service", hint)


def add_drive_arguments(parser: argparse.ArgumentParser, turn_rate: float) -> None:
    """``--speed`` and ``--turn-rate``, as every tool that drives the robot takes them."""
    parser.add_argument("--speed", type=float, default=0.2, help="forward speed, m/s (default 0.2)")
    parser.add_argument("--turn-rate", type=float, default=turn_rate, help=f"turn rate, rad/s (default {turn_rate:g})")


def connect(args: argparse.Namespace, waiting: tuple[threading.Event, str] | None = None) -> tuple[Keys, ZenohSettings, Any]:
    """The key space, the Zenoh settings and an open session; ``waiting`` (stop event, name): a service (the
    recorder) waits for its endpoint, the session None if stopped first."""
    keys = Keys(getattr(args, "prefix", DEFAULT_PREFIX))
    settings = zenoh_settings(args)
    return keys, settings, open_session(settings) if waiting is None else open_when_reachable(settings, *waiting)


def tool(name: str) -> Callable[[Callable[[argparse.Namespace], int]], Callable[[argparse.Namespace], int]]:
    """Decorate a tool's ``run``: a BlackmetalError (up's failed child too) ends it with one line on stderr (exit 1, or 2 for settings)."""

    def wrap(run: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
        @functools.wraps(run)
        def wrapper(args: argparse.Namespace) -> int:
            try:
                return run(args)
            except BlackmetalError as exc:
                print(f"blackmetal {name}: {exc}", file=sys.stderr)
                return 1 if isinstance(exc, ToolError | ZenohUnavailable | ChildFailed) else 2

        return wrapper

    return wrap
