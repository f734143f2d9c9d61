"""Every child process the bench starts, and how they all stop: none outlives the bench.

Each figure stops its own children in a ``finally``; :func:`stop_all` and :func:`shutdown` are the net
under those. The first SIGINT or SIGTERM raises ``KeyboardInterrupt`` so every ``finally`` runs; later
signals are ignored so the cleanup is never cut short.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from types import FrameType
from typing import Any

from blackmetal.runtime.harness import ServiceProcess, stop_in_order

#: How long children get to stop after SIGINT before they are killed.
GRACE_S = 5.0

_children: list[ServiceProcess] = []


class _State:
    signum: int | None = None  # the signal that asked the bench to stop
    held: bool = False  # that signal came while it had to wait
    holding: int = 0  # depth of sections a signal must not interrupt
    closing: bool = False  # shutting down: signals are only noted


_state = _State()


def _on_signal(signum: int, frame: FrameType | None) -> None:
    if _state.signum is not None:
        return  # already stopping: let the cleanup run to its end
    _state.signum = signum
    if _state.holding or _state.closing:
        _state.held = True
        return
    raise KeyboardInterrupt


@contextmanager
def _held() -> Iterator[None]:
    """A section that a stop signal does not interrupt; a signal that came meanwhile is raised at its end."""
    _state.holding += 1
    try:
        yield
    finally:
        _state.holding -= 1
    if _state.held and not _state.holding and not _state.closing:
        _state.held = False
        raise KeyboardInterrupt


def stop_signal() -> int | None:
    """The signal (SIGINT or SIGTERM) that asked the bench to stop, if one did."""
    return _state.signum


@contextmanager
def stopping_on_signals() -> Iterator[None]:
    """SIGINT and SIGTERM raise KeyboardInterrupt once (in the main thread); the former handlers come back at the end."""
    _state.signum, _state.held, _state.closing = None, False, False
    previous = {sig: signal.signal(sig, _on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def spawn(name: str, args: list[str], **kwargs: Any) -> ServiceProcess:
    """A child process (``python ARGS``), stopped by :func:`stop_all` at the latest."""
    with _held():
        child = ServiceProcess(name, args, **kwargs)
        _children.append(child)
    return child


def stop_all(grace: float = GRACE_S) -> None:
    """Stop every child that :func:`spawn` started and that still runs: SIGINT, SIGKILL after ``grace`` seconds."""
    with _held():
        live = [child for child in _children if child.poll() is None]
        stop_in_order([live], grace)
        for child in _children:
            child.stop(timeout=1.0)  # exited by now: reaps it, joins its output reader, closes its pipes
        _children.clear()


def shutdown() -> None:
    """The bench ends: from here signals are only noted; every child is stopped, and any other process whose parent we are."""
    _state.closing = True
    stop_all()
    strays = _own_children()
    for pid in strays:
        with suppress(ProcessLookupError):
            os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + GRACE_S
    while strays and time.monotonic() < deadline:
        strays = [pid for pid in strays if not _reaped(pid)]
        time.sleep(0.02)
    for pid in strays:
        with suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
        _reaped(pid, block=True)


def _own_children() -> list[int]:
    """Processes whose parent is this one and that still run (zombies left out), from /proc."""
    me, found = os.getpid(), []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[1]) == me and fields[0] != "Z":
            found.append(int(entry))
    return found


def _reaped(pid: int, block: bool = False) -> bool:
    try:
        done, _ = os.waitpid(pid, 0 if block else os.WNOHANG)
    except ChildProcessError:
        return True  # reaped elsewhere
    return done == pid
