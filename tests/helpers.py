"""Test helpers: free ports, loopback Zenoh configs, child processes, condition waits."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import zenoh

#: Generous: these tests must hold on a loaded 2-core machine.
TIMEOUT = 20.0


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def wait_for(condition: Callable[[], Any], timeout: float = TIMEOUT, interval: float = 0.02, what: str = "condition") -> Any:
    """Poll ``condition`` until it returns something truthy; fail after ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(interval)


def zenoh_listen_args(port: int) -> list[str]:
    return ["--no-multicast-scouting", "-l", f"tcp/127.0.0.1:{port}"]


def zenoh_connect_args(port: int) -> list[str]:
    return ["--no-multicast-scouting", "-e", f"tcp/127.0.0.1:{port}"]


def client_config(port: int) -> zenoh.Config:
    """A peer that connects to a process listening on ``port``, multicast scouting off."""
    conf = zenoh.Config()
    conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


class Child:
    """A child process whose output is collected by a thread (so pipes never fill)."""

    def __init__(self, args: list[str], env: dict[str, str] | None = None, launcher: list[str] | None = None) -> None:
        full_env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.args = args
        self.proc = subprocess.Popen(
            [*(launcher or []), sys.executable, *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env=full_env,
            text=True,
        )
        self.lines: deque[str] = deque(maxlen=2000)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def output(self) -> str:
        return "\n".join(self.lines)

    def wait_line(self, pattern: str, timeout: float = TIMEOUT) -> re.Match[str]:
        regex = re.compile(pattern)

        def found() -> re.Match[str] | None:
            for line in list(self.lines):
                match = regex.search(line)
                if match:
                    return match
            if self.proc.poll() is not None:
                raise AssertionError(f"{self.args} exited with {self.proc.returncode}:\n{self.output()}")
            return None

        try:
            return wait_for(found, timeout, what=f"a line matching {pattern!r}")
        except AssertionError as exc:
            raise AssertionError(f"{exc}\noutput so far:\n{self.output()}") from None

    def stop(self, sig: int = signal.SIGINT, timeout: float = 10.0) -> int:
        """Signal the child and wait; kill it if it does not exit in time."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self._reader.join(2)
        return self.proc.returncode


class SimProcess(Child):
    """``blackmetal sim`` on free ports; ``control_port``/``log_port`` once ready."""

    def __init__(self, *extra: str, launcher: list[str] | None = None) -> None:
        super().__init__(["-m", "gateway.cli", "sim", "--control-port", "0", "--log-port", "0", *extra], launcher=launcher)
        match = self.wait_line(r"control (\S+):(\d+), log (\S+):(\d+)")
        self.host = match.group(1)
        self.control_port = int(match.group(2))
        self.log_port = int(match.group(4))
