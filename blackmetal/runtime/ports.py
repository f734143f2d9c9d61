"""Free loopback ports for processes we start ourselves (the bench, the tests), that nobody can take first.

A port-0 probe hands out an ephemeral port that any ``connect()`` may take before the child binds it (CI saw it); the
kernel never hands out ports below its ephemeral range, so this walks a slice of those, binding each to check.
pytest-xdist workers get disjoint slices; a random start keeps two runs apart.
"""

from __future__ import annotations

import os
import random
import socket
import threading

#: The lowest port handed out; below it live well-known services (and Zenoh's 7447).
LOWEST = 10000
#: Disjoint slices: one per pytest-xdist worker (gw0 ... gw7, then round again).
SLICES = 8


def ephemeral_low() -> int:
    """The first port of the kernel's ephemeral range (Linux: /proc; elsewhere its default)."""
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as ranges:
            return int(ranges.read().split()[0])
    except (OSError, ValueError, IndexError):
        return 49152  # IANA's dynamic range, macOS and Windows


def bindable(port: int, host: str = "127.0.0.1") -> bool:
    """Whether nothing holds ``port`` on ``host`` right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        try:
            sock.bind((host, port))
        except OSError:
            return False
    return True


class PortAllocator:
    """Hands out each port of ``ports`` once per lap, skipping those in use."""

    def __init__(self, ports: range, start: int | None = None) -> None:
        self.ports = ports
        self._next = ports.start if start is None else start
        self._lock = threading.Lock()

    def free(self, count: int = 1) -> int:
        """A base port B with B ... B + count - 1 free now (recipes number their robots' ports from a base)."""
        ports = self.ports
        with self._lock:
            for _ in range(len(ports)):
                base = self._next if self._next + count <= ports.stop else ports.start
                self._next = base + count if base + count < ports.stop else ports.start
                if all(bindable(port) for port in range(base, base + count)):
                    return base
        raise OSError(f"no {count} free consecutive port(s) in {self.ports.start}-{self.ports.stop - 1}")


def worker_slice() -> range:
    """This process's slice: by its pytest-xdist worker number, the first slice otherwise."""
    high = max(ephemeral_low(), LOWEST + 2000)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw")
    index = int(worker) % SLICES if worker.isdigit() else 0
    size = (high - LOWEST) // SLICES
    return range(LOWEST + index * size, LOWEST + (index + 1) * size)


_SLICE = worker_slice()
_ALLOCATOR = PortAllocator(_SLICE, start=_SLICE.start + random.randrange(len(_SLICE)))


def free_port(count: int = 1) -> int:
    """A free loopback port (or the base of ``count`` consecutive ones) that no outgoing connection can take."""
    return _ALLOCATOR.free(count)
