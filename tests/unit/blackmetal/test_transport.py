"""Byte streams to the robot: what is read is pushed to the reader in order, in bounded chunks, and every ending is told."""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable, Coroutine
from typing import Any

import pytest

from blackmetal.transport import CHUNK, ByteStream, TcpStream, memory_pipe

Runner = Callable[[Coroutine[Any, Any, None]], None]


async def tcp_pair() -> tuple[ByteStream, socket.socket]:
    """A TcpStream and the plain socket at its other end (the robot)."""
    server = socket.create_server(("127.0.0.1", 0))
    server.setblocking(False)
    loop = asyncio.get_running_loop()
    accepted = loop.create_task(loop.sock_accept(server))
    stream = await TcpStream.connect("127.0.0.1", server.getsockname()[1], write_now=True)
    peer, _ = await asyncio.wait_for(accepted, 10)
    server.close()
    peer.setblocking(False)
    return stream, peer


async def pump_into(stream: ByteStream, got: list[bytes]) -> asyncio.Task[None]:
    task = asyncio.get_running_loop().create_task(stream.pump(got.append))
    await asyncio.sleep(0)
    return task


async def wait_for(condition: object, timeout: float = 10.0) -> None:
    async def until() -> None:
        while not condition():  # type: ignore[operator]
            await asyncio.sleep(0.002)

    await asyncio.wait_for(until(), timeout)


def test_tcp_bytes_reach_the_pump_in_order_and_the_peer_closing_ends_it(run_loop: Runner) -> None:
    async def main() -> None:
        stream, peer = await tcp_pair()
        loop = asyncio.get_running_loop()
        await loop.sock_sendall(peer, b"before the pump, ")  # kept until someone pumps
        await asyncio.sleep(0.05)
        got: list[bytes] = []
        pumping = await pump_into(stream, got)
        for part in (b"one ", b"two ", b"three"):
            await loop.sock_sendall(peer, part)
        await wait_for(lambda: b"".join(got) == b"before the pump, one two three")
        peer.close()
        await asyncio.wait_for(pumping, 10)  # returns: the robot closed
        stream.close()

    run_loop(main())


def test_a_flood_is_handed_over_in_chunks_with_the_loop_running_between_them(run_loop: Runner) -> None:
    async def main() -> None:
        stream, peer = await tcp_pair()
        loop = asyncio.get_running_loop()
        ticks = [0]
        seen_at: list[int] = []

        def deliver(data: bytes) -> None:
            assert len(data) <= CHUNK
            seen_at.append(ticks[0])
            got.append(data)

        def tick() -> None:
            ticks[0] += 1
            loop.call_soon(tick)

        got: list[bytes] = []
        pumping = loop.create_task(stream.pump(deliver))
        flood = bytes(range(256)) * 1024  # 256 KiB, one write
        peer.setblocking(True)
        peer.sendall(flood)
        loop.call_soon(tick)
        await wait_for(lambda: sum(map(len, got)) == len(flood))
        assert b"".join(got) == flood
        assert len(got) >= len(flood) // CHUNK
        assert seen_at[-1] > seen_at[0]  # other callbacks ran while the flood was being handed over
        stream.close()
        peer.close()
        await asyncio.wait_for(pumping, 10)

    run_loop(main())


def test_what_the_reader_raises_ends_the_pump_and_closes_the_link(run_loop: Runner) -> None:
    async def main() -> None:
        stream, peer = await tcp_pair()
        loop = asyncio.get_running_loop()

        def deliver(data: bytes) -> None:
            raise ValueError("a bug in the reader")

        pumping = loop.create_task(stream.pump(deliver))
        await loop.sock_sendall(peer, b"x")
        with pytest.raises(ValueError, match="a bug"):
            await asyncio.wait_for(pumping, 10)
        assert stream.is_closing()
        stream.close()  # as the gateway does once the pump ended: its duplicate for sends from other threads goes too
        assert await asyncio.wait_for(loop.sock_recv(peer, 16), 10) == b""  # the robot sees the link end
        peer.close()

    run_loop(main())


def test_drain_waits_for_a_full_socket_and_raises_once_the_link_is_gone(run_loop: Runner) -> None:
    async def main() -> None:
        stream, peer = await tcp_pair()
        got: list[bytes] = []
        pumping = await pump_into(stream, got)
        stream.write(b"y" * 20_000_000)  # far more than the socket buffers take
        drained = asyncio.get_running_loop().create_task(stream.drain())
        await asyncio.sleep(0.1)
        assert not drained.done()  # the robot reads nothing: the writer waits
        peer.close()
        with pytest.raises(ConnectionError):
            await asyncio.wait_for(drained, 10)
        with pytest.raises(ConnectionError):
            await asyncio.wait_for(pumping, 10)
        stream.close()

    run_loop(main())


def test_a_memory_pipe_pumps_like_a_socket(run_loop: Runner) -> None:
    async def main() -> None:
        ours, theirs = memory_pipe()
        got: list[bytes] = []
        theirs.write(b"early ")
        pumping = await pump_into(ours, got)
        theirs.write(b"late")
        await wait_for(lambda: b"".join(got) == b"early late")
        theirs.close()
        await asyncio.wait_for(pumping, 10)
        assert ours.is_closing()

    run_loop(main())


def test_bytes_read_before_the_pump_are_handed_over_in_chunks_too(run_loop: Runner) -> None:
    async def main() -> None:
        stream, peer = await tcp_pair()
        early = bytes(range(256)) * 800  # 200 KiB before anyone pumps (a robot that talks as soon as it is connected)
        peer.setblocking(True)
        peer.sendall(early)
        await asyncio.sleep(0.2)
        got: list[bytes] = []
        pumping = await pump_into(stream, got)
        await wait_for(lambda: sum(map(len, got)) == len(early))
        assert b"".join(got) == early and max(map(len, got)) <= CHUNK
        stream.close()
        peer.close()
        await asyncio.wait_for(pumping, 10)

    run_loop(main())


def test_what_the_reader_raises_on_early_bytes_ends_the_pump_and_closes_the_link(run_loop: Runner) -> None:
    async def main() -> None:
        stream, peer = await tcp_pair()
        loop = asyncio.get_running_loop()
        await loop.sock_sendall(peer, b"hello")
        await asyncio.sleep(0.1)

        def deliver(data: bytes) -> None:
            raise ValueError("a bug in the reader")

        with pytest.raises(ValueError, match="a bug"):
            await asyncio.wait_for(stream.pump(deliver), 10)
        assert stream.is_closing()
        stream.close()
        assert await asyncio.wait_for(loop.sock_recv(peer, 16), 10) == b""
        peer.close()

    run_loop(main())


def test_a_peer_is_made_to_wait_while_nobody_pumps(run_loop: Runner) -> None:
    async def main() -> None:
        stream, peer = await tcp_pair()
        block = b"z" * 65536
        sent = 0
        started = asyncio.get_running_loop().time()
        while asyncio.get_running_loop().time() - started < 1.0 and sent < 200_000_000:
            try:
                sent += peer.send(block)
            except BlockingIOError:
                await asyncio.sleep(0.01)  # the loop reads (or not) meanwhile
        assert sent < 50_000_000  # the socket buffers, and no more: reading paused once EARLY_LIMIT was held
        got: list[bytes] = []
        pumping = await pump_into(stream, got)  # then everything sent arrives
        await wait_for(lambda: sum(map(len, got)) == sent)
        stream.close()
        peer.close()
        await asyncio.wait_for(pumping, 10)

    run_loop(main())


def test_a_cancelled_pump_hands_nothing_more_to_its_reader(run_loop: Runner) -> None:
    async def main() -> None:
        stream, peer = await tcp_pair()
        loop = asyncio.get_running_loop()
        got: list[bytes] = []
        pumping = await pump_into(stream, got)
        await loop.sock_sendall(peer, b"before")
        await wait_for(lambda: got == [b"before"])
        pumping.cancel()
        with pytest.raises(asyncio.CancelledError):
            await pumping
        await loop.sock_sendall(peer, b"after the cancel")
        await asyncio.sleep(0.2)
        assert got == [b"before"]
        stream.close()
        peer.close()

    run_loop(main())


def test_closing_a_link_the_peer_stopped_reading_ends_it_at_once(run_loop: Runner) -> None:
    async def main() -> None:
        stream, peer = await tcp_pair()
        got: list[bytes] = []
        pumping = await pump_into(stream, got)
        stream.write(b"w" * 20_000_000)  # the robot reads none of it
        await asyncio.sleep(0.1)
        stream.close()
        await asyncio.wait_for(asyncio.shield(pumping), 5)  # not when TCP gives up, minutes later
        peer.close()

    run_loop(main())
