"""The port allocator the bench and the tests share: ports nobody else can be handed first."""

from __future__ import annotations

import socket

from blackmetal.runtime.ports import PortAllocator, ephemeral_low, free_port, worker_slice


def test_ports_come_from_below_the_kernels_ephemeral_range() -> None:
    taken = [free_port() for _ in range(50)]
    assert len(set(taken)) == 50, "a port handed out twice in one lap"
    assert all(port in worker_slice() for port in taken)
    assert max(taken) < ephemeral_low(), "bind(0) and every connect() draw from the ephemeral range; ours must not"


def test_a_port_in_use_is_skipped() -> None:
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        held = holder.getsockname()[1]
        holder.listen()
        allocator = PortAllocator(range(held, held + 3))
        # skipped; the next one may itself be taken by another test's process on a busy machine (a CI run saw it)
        assert allocator.free() in (held + 1, held + 2)


def test_a_block_is_free_throughout_and_the_next_caller_starts_after_it() -> None:
    start = free_port(10)
    allocator = PortAllocator(range(start, start + 10))
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", start + 1))  # the first block of three would straddle it
        base = allocator.free(3)
    assert start + 1 not in range(base, base + 3)
    assert allocator.free() == base + 3
