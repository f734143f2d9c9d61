"""Child processes started one way everywhere: ``blackmetal up``, the bench and the tests.

Readiness is machine-readable: the parent passes the write end of a pipe in ``BLACKMETAL_READY_FD``, and a service that
is ready writes one JSON object on it (:func:`announce_ready`: its name and what a parent needs, such as the simulator's
bound ports). Text meant for people (stdout, stderr) is kept, the last lines of it, to show when a child fails; it is
never parsed.
"""

from __future__ import annotations

import json
import os
import queue
import select
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from typing import Any

from blackmetal.schemas import BlackmetalError

READY_FD_ENV = "BLACKMETAL_READY_FD"
#: Set for a child in its own session: the pid of the parent it must not outlive (:func:`end_with_parent`).
PARENT_PID_ENV = "BLACKMETAL_PARENT_PID"


def end_with_parent() -> None:
    """A child the harness put in its own session (``up``'s) gets SIGTERM, its orderly stop, when its parent dies.

    Ctrl-C never reaches such a child, so without this a ``kill -9`` of ``up`` left its gateway, odometry and
    simulator running. Linux only (``PR_SET_PDEATHSIG``); the parent must spawn from a thread that lives as long
    as it does (``up`` spawns from its main thread).
    """
    parent = os.environ.pop(PARENT_PID_ENV, None)
    if not parent or not sys.platform.startswith("linux"):
        return
    import ctypes

    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # 1: PR_SET_PDEATHSIG
    if os.getppid() != int(parent):  # the parent died before the call above: nobody will send the signal
        os.kill(os.getpid(), signal.SIGTERM)


def announce_ready(service: str, **info: Any) -> None:
    """Tell the parent (if a harness started us) that ``service`` is ready, with ``info``."""
    fd_text = os.environ.pop(READY_FD_ENV, None)
    if not fd_text:
        return
    try:
        fd = int(fd_text)
        os.write(fd, (json.dumps({"service": service, **info}) + "\n").encode())
        os.close(fd)
    except (OSError, ValueError):
        pass  # the parent went away or passed nonsense: running on is still right


class ChildFailed(BlackmetalError):
    """A child exited, did not become ready or did not answer in time; the text carries its last lines."""

    def __init__(self, child: "ServiceProcess", what: str) -> None:
        self.child = child
        super().__init__(f"{child.name} {what}; its last lines:\n{child.tail()}")


class ServiceProcess:
    """One child Python process, its output collected by a thread (so pipes never fill)."""

    def __init__(
        self,
        name: str,
        args: list[str],
        env: dict[str, str] | None = None,
        launcher: list[str] | None = None,
        echo: bool = False,
        own_session: bool = False,
        interactive: bool = False,
    ) -> None:
        self.name = name
        self.args = args
        self.echo = echo
        self.lines: deque[str] = deque(maxlen=2000)
        #: With ``interactive``, the child's stdin is ours and its stdout lines also queue up for :meth:`request`.
        self._replies: queue.SimpleQueue[str] | None = queue.SimpleQueue() if interactive else None
        self.ready_info: dict[str, Any] | None = None
        self._ready_fd, write_fd = os.pipe()
        try:
            self.proc = subprocess.Popen(
                [*(launcher or []), sys.executable, *args],
                stdin=subprocess.PIPE if interactive else subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                env={
                    **os.environ,
                    "PYTHONUNBUFFERED": "1",
                    **(env or {}),
                    READY_FD_ENV: str(write_fd),
                    **({PARENT_PID_ENV: str(os.getpid())} if own_session else {}),
                },
                text=True,
                pass_fds=(write_fd,),
                start_new_session=own_session,  # Ctrl-C reaches the parent only; it stops children in order
            )
        finally:
            os.close(write_fd)
        self._reader = threading.Thread(target=self._read, name=f"{name}-output", daemon=True)
        self._reader.start()

    @classmethod
    def blackmetal(cls, name: str, command: list[str], **kwargs: Any) -> "ServiceProcess":
        return cls(name, ["-m", "blackmetal", *command], **kwargs)

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            line = line.rstrip("\n")
            self.lines.append(line)
            if self._replies is not None:
                self._replies.put(line)
            if self.echo:
                print(f"[{self.name}] {line}", flush=True)

    def wait_ready(self, timeout: float = 30.0) -> dict[str, Any]:
        """The child's ready announcement; ChildFailed if it exits or stays silent for ``timeout``."""
        if self.ready_info is not None:
            return self.ready_info
        deadline = time.monotonic() + timeout
        buffer = b""
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise ChildFailed(self, f"did not become ready within {timeout:g} s")
            readable, _, _ = select.select([self._ready_fd], [], [], min(remaining, 0.1))
            if readable:
                chunk = os.read(self._ready_fd, 65536)
                buffer += chunk
                if b"\n" in buffer:
                    self.ready_info = json.loads(buffer.split(b"\n", 1)[0])
                    os.close(self._ready_fd)
                    self._ready_fd = -1
                    return self.ready_info
                if not chunk:  # the child closed the pipe without a word: it has exited
                    self.proc.wait(5)
                    raise ChildFailed(self, f"exited with code {self.proc.returncode} before it was ready")

    def request(self, line: str, timeout: float = 30.0) -> str:
        """Send one line to an interactive child and return the next line it prints."""
        assert self._replies is not None and self.proc.stdin is not None, "not an interactive child"
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        try:
            return self._replies.get(timeout=timeout)
        except queue.Empty:
            raise ChildFailed(self, f"did not answer {line!r} within {timeout:g} s") from None

    def output(self) -> str:
        return "\n".join(self.lines)

    def tail(self, count: int = 15) -> str:
        return "\n".join(f"    {line}" for line in list(self.lines)[-count:]) or "    (no output)"

    def poll(self) -> int | None:
        return self.proc.poll()

    def send_signal(self, sig: int) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.send_signal(sig)
            except ProcessLookupError:
                pass

    def wait(self, timeout: float) -> int:
        """Wait for the child to exit by itself and for its last output lines to be read; its exit code."""
        code = self.proc.wait(timeout)
        self._reader.join(5)
        return code

    def stop(self, sig: int = signal.SIGINT, timeout: float = 10.0) -> int:
        """Signal the child and wait; kill it if it does not exit in time. Returns its exit code."""
        self.send_signal(sig)
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
        self._reader.join(2)
        if self._ready_fd >= 0:
            os.close(self._ready_fd)
            self._ready_fd = -1
        return self.proc.returncode


def stop_in_order(groups: list[list[ServiceProcess]], budget: float) -> None:
    """SIGINT each group in turn and wait its share of ``budget`` seconds; kill what is left at the end."""
    deadline = time.monotonic() + budget
    for index, group in enumerate(groups):
        for child in group:
            child.send_signal(signal.SIGINT)
        share = (time.monotonic() + (deadline - time.monotonic()) / (len(groups) - index)) if groups else deadline
        for child in group:
            try:
                child.proc.wait(max(share - time.monotonic(), 0.01))
            except subprocess.TimeoutExpired:
                pass
    for group in groups:
        for child in group:
            if child.proc.poll() is None:
                child.proc.kill()
                child.proc.wait(1)
