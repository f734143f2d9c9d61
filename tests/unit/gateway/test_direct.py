"""A single robot's direct path on its own: who may take an input directly, what goes to the robot now, what waits.

The direct take through a whole gateway host (the intake, a real loop, TCP)
is in tests/unit/gateway/test_direct_take.py.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Iterator
from typing import TypeVar

import pytest

from blackmetal.gateway.direct import DirectPath

T = TypeVar("T")


class Stream:
    """A control stream that takes ``room`` bytes at once from another thread, and records them."""

    def __init__(self, room: int = 1 << 20) -> None:
        self.room = room
        self.sent = b""
        self.closing = False
        self.calls = 0

    def write_now(self, data: bytes) -> int:
        self.calls += 1
        taken = data[: self.room]
        self.room -= len(taken)
        self.sent += taken
        return len(taken)

    def is_closing(self) -> bool:
        return self.closing


def on_another_thread(call: Callable[[], T]) -> T:
    """``call`` as a Zenoh thread would make it."""
    result: list[T] = []
    thread = threading.Thread(target=lambda: result.append(call()))
    thread.start()
    thread.join(5)
    return result[0]


@pytest.fixture
def loop() -> Iterator[asyncio.AbstractEventLoop]:
    """The host's loop, not running: what a send schedules on it waits until :func:`turn`."""
    made = asyncio.new_event_loop()
    yield made
    made.close()


def turn(loop: asyncio.AbstractEventLoop) -> None:
    """One turn of the loop: the callbacks scheduled so far run."""
    loop.run_until_complete(asyncio.sleep(0))


def test_only_another_thread_may_take_an_input_and_only_while_the_host_runs(loop: asyncio.AbstractEventLoop) -> None:
    path = DirectPath()
    assert not path.allowed() and not on_another_thread(path.allowed), "the host does not run yet"
    path.open(loop)  # on this thread: it is the loop's
    assert not path.allowed(), "the loop's own thread never takes the direct path"
    assert on_another_thread(path.allowed)
    path.shut()
    assert not on_another_thread(path.allowed), "a stopped or failed host takes every input on its loop"


def test_bytes_go_to_the_robot_at_once_and_the_loop_flushes_once(loop: asyncio.AbstractEventLoop) -> None:
    path, stream, flushes = DirectPath(), Stream(), []
    path.open(loop)
    path.stream_up(stream)  # type: ignore[arg-type]
    with path.lock:
        path.send(path.before(b"cmd 1;"), lambda: flushes.append(1))
        path.send(path.before(b"cmd 2;"), lambda: flushes.append(2))
    assert stream.sent == b"cmd 1;cmd 2;", "sent on the calling thread, before the loop wakes"
    assert flushes == []
    turn(loop)
    assert flushes == [1], "one flush for inputs taken before the loop's turn, not one each"
    path.flushed()
    path.send(path.before(b"cmd 3;"), lambda: flushes.append(3))
    turn(loop)
    assert flushes == [1, 3]


def test_what_the_stream_could_not_take_now_goes_first_in_the_loops_next_write(loop: asyncio.AbstractEventLoop) -> None:
    path, stream = DirectPath(), Stream(room=4)
    path.open(loop)
    path.stream_up(stream)  # type: ignore[arg-type]
    path.send(path.before(b"estop on;"), lambda: None)
    assert stream.sent == b"esto"
    assert path.before(b"status;") == b"p on;status;", "the rest, oldest first, before anything newer"
    assert path.before(b"status;") == b"status;", "and only once"


def test_a_direct_send_after_a_rest_sends_the_rest_first(loop: asyncio.AbstractEventLoop) -> None:
    path, stream = DirectPath(), Stream(room=4)
    path.open(loop)
    path.stream_up(stream)  # type: ignore[arg-type]
    path.send(path.before(b"estop on;"), lambda: None)
    stream.room = 100
    path.send(path.before(b"cmd;"), lambda: None)
    assert stream.sent == b"estop on;cmd;"


def test_nothing_is_written_without_a_stream_or_to_a_closing_one_and_a_new_link_gets_none_of_it(loop: asyncio.AbstractEventLoop) -> None:
    """A reconnect never resumes old motion: bytes meant for a link that went are dropped with it."""
    path = DirectPath()
    path.open(loop)
    path.send(path.before(b"cmd old;"), lambda: None)  # no stream yet: kept for the loop
    closing = Stream()
    closing.closing = True
    path.stream_up(closing)  # type: ignore[arg-type]
    path.send(path.before(b"cmd older;"), lambda: None)
    assert closing.calls == 0 and closing.sent == b""
    path.stream_down()
    fresh = Stream()
    path.stream_up(fresh)  # type: ignore[arg-type]
    assert path.before(b"cmd new;") == b"cmd new;"


def test_an_empty_send_writes_nothing_but_still_has_the_loop_publish(loop: asyncio.AbstractEventLoop) -> None:
    """An input that produced no bytes (a refused command) may still have produced reports to publish."""
    path, stream, flushes = DirectPath(), Stream(), []
    path.open(loop)
    path.stream_up(stream)  # type: ignore[arg-type]
    path.send(b"", lambda: flushes.append("flush"))
    turn(loop)
    assert stream.calls == 0 and flushes == ["flush"]


def test_a_send_after_the_host_stopped_or_its_loop_closed_schedules_nothing_and_raises_nothing() -> None:
    path, stream, flushes = DirectPath(), Stream(), []
    closed = asyncio.new_event_loop()
    path.open(closed)
    path.stream_up(stream)  # type: ignore[arg-type]
    closed.close()
    path.send(b"cmd;", lambda: flushes.append("flush"))  # the loop is gone: nothing to schedule on
    assert stream.sent == b"cmd;"
    path.flushed()
    path.shut()
    path.send(b"cmd;", lambda: flushes.append("flush"))
    assert flushes == []
