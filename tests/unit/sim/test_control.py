"""The simulated robot's control session: replies in request order whatever the link faults hold back or delay."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Coroutine
from typing import Any

from blackmetal import wire
from blackmetal.schemas import SimFaults
from blackmetal.sim.control import GLUE_HOLD_S, ControlSession
from blackmetal.sim.physics import SimRobot
from blackmetal.wire import CommandCode, Malformed, ReplyDecoder, SpeedReading, StatusReply

Runner = Callable[[Coroutine[Any, Any, None]], None]


class Sink:
    """What the session writes, with the loop time of each write."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        self.writes: list[tuple[float, bytes]] = []
        self.closed = False

    def write(self, data: bytes) -> None:
        assert not self.closed, "written after close"
        self.writes.append((self.loop.time(), data))

    def close(self) -> None:
        self.closed = True

    def is_closing(self) -> bool:
        return self.closed

    def replies(self) -> list[object]:
        decoder = ReplyDecoder()
        items = [item for _, data in self.writes for item in decoder.feed(data)]
        return [item for item in items if not isinstance(item, Malformed)]


def session_for(faults: SimFaults, loop: asyncio.AbstractEventLoop, seed: int = 7) -> tuple[ControlSession, Sink, list[int]]:
    robot = SimRobot(now=time.monotonic(), seed=seed)
    robot.faults = faults
    sink = Sink(loop)
    malformed: list[int] = []
    return ControlSession(robot, sink, time.monotonic, loop, lambda: malformed.append(1)), sink, malformed


def requests(count: int) -> bytes:
    """``count`` pairs of a velocity command and a poll, in one write."""
    one = wire.encode_request(wire.set_velocity(left=0.1, right=0.1)) + wire.encode_request(wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY))
    return one * count


def expected(count: int) -> list[type]:
    # a velocity command: one status; a poll: a status and a reading
    return [StatusReply, StatusReply, SpeedReading] * count


#: The loop clock's step under uvloop (s); a sum of two of its times may round a hair above a third.
CLOCK_STEP_S = 0.001


async def wait_until(condition: object, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():  # type: ignore[operator]
        assert time.monotonic() < deadline, "timed out"
        await asyncio.sleep(0.005)


def test_without_faults_every_reply_is_written_at_once(run_loop: Runner) -> None:
    async def main() -> None:
        session, sink, _ = session_for(SimFaults(), asyncio.get_running_loop())
        session.feed(requests(3))
        assert [type(r) for r in sink.replies()] == expected(3)  # written inside feed, no timer

    run_loop(main())


def test_delayed_and_split_replies_keep_their_order_and_their_delay(run_loop: Runner) -> None:
    async def main() -> None:
        loop = asyncio.get_running_loop()
        session, sink, _ = session_for(SimFaults(delay=0.05, split=1.0), loop)
        fed_at = loop.time()
        session.feed(requests(5))
        assert sink.writes == []
        await wait_until(lambda: len(sink.replies()) == 15)
        assert [type(r) for r in sink.replies()] == expected(5)
        assert min(at for at, _ in sink.writes) >= fed_at + 0.05 - CLOCK_STEP_S
        assert len(sink.writes) > 15  # every reply went out in two parts

    run_loop(main())


def test_a_reply_without_delay_never_overtakes_a_delayed_one(run_loop: Runner) -> None:
    async def main() -> None:
        loop = asyncio.get_running_loop()
        session, sink, _ = session_for(SimFaults(delay=0.05), loop)
        session.feed(requests(1))
        session.robot.faults = SimFaults()  # the delay is lifted while a reply still waits
        session.feed(wire.encode_request(wire.simple(CommandCode.NORMAL_STOP)))
        assert sink.writes == []
        await wait_until(lambda: len(sink.replies()) == 4)
        assert [type(r) for r in sink.replies()] == [*expected(1), StatusReply]

    run_loop(main())


def test_glued_replies_come_together_or_after_the_hold(run_loop: Runner) -> None:
    async def main() -> None:
        loop = asyncio.get_running_loop()
        session, sink, _ = session_for(SimFaults(glue=1.0), loop)
        fed_at = loop.time()
        session.feed(requests(2))
        assert sink.writes == []
        await wait_until(lambda: sink.writes)
        # uvloop's clock counts whole milliseconds: 33450.76 + 0.05 is a hair over the 33450.81 it fires at
        assert len(sink.writes) == 1 and sink.writes[0][0] >= fed_at + GLUE_HOLD_S - CLOCK_STEP_S
        assert [type(r) for r in sink.replies()] == expected(2)

    run_loop(main())


def test_garbage_before_a_reply_is_skipped_by_the_client_and_loses_nothing(run_loop: Runner) -> None:
    async def main() -> None:
        session, sink, _ = session_for(SimFaults(garbage=1.0), asyncio.get_running_loop())
        session.feed(requests(4))
        assert [type(r) for r in sink.replies()] == expected(4)

    run_loop(main())


def test_a_dropped_connection_closes_the_sink_and_answers_nothing_more(run_loop: Runner) -> None:
    async def main() -> None:
        session, sink, _ = session_for(SimFaults(disconnect=1.0), asyncio.get_running_loop())
        session.feed(requests(2))
        assert sink.closed and sink.writes == [] and session.sink.is_closing()

    run_loop(main())


def test_closing_drops_what_waits_and_writes_nothing_later(run_loop: Runner) -> None:
    async def main() -> None:
        session, sink, _ = session_for(SimFaults(delay=0.02, glue=0.5), asyncio.get_running_loop())
        session.feed(requests(4))
        session.close()
        await asyncio.sleep(0.1)  # the timers that were set would have fired by now
        assert sink.writes == []  # Sink asserts on a write after close

    run_loop(main())


def test_a_silent_robot_acts_on_commands_but_answers_nothing(run_loop: Runner) -> None:
    async def main() -> None:
        session, sink, _ = session_for(SimFaults(silent=True), asyncio.get_running_loop())
        session.feed(requests(1))
        assert sink.writes == [] and session.robot.target_left > 0

    run_loop(main())


def test_a_malformed_request_is_counted_and_the_next_one_answered(run_loop: Runner) -> None:
    async def main() -> None:
        session, sink, malformed = session_for(SimFaults(), asyncio.get_running_loop())
        session.feed(b'{"command":"FLY"}' + wire.encode_request(wire.simple(CommandCode.NORMAL_STOP)))
        assert malformed == [1]
        assert [type(r) for r in sink.replies()] == [StatusReply]

    run_loop(main())


def test_a_delayed_reply_wakes_the_loop_about_once(run_loop: Runner) -> None:
    async def main() -> None:
        loop = asyncio.get_running_loop()
        session, sink, _ = session_for(SimFaults(delay=0.0104, split=1.0), loop)
        wakes = [0]
        write_due = session._write_due

        def counting() -> None:
            wakes[0] += 1
            write_due()

        session._write_due = counting  # type: ignore[method-assign]
        for _ in range(20):
            session.feed(wire.encode_request(wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY)))
            await asyncio.sleep(0.005)
        await wait_until(lambda: len(sink.replies()) == 40)
        assert wakes[0] <= 4 * 40  # two parts a reply; a timer that woke early and was set again at once woke thousands

    run_loop(main())


def test_requests_read_before_a_drop_never_reach_the_robot(run_loop: Runner) -> None:
    async def main() -> None:
        session, sink, _ = session_for(SimFaults(), asyncio.get_running_loop())
        session.close()  # a new client took over; a memory pipe still hands over what it had buffered
        session.feed(wire.encode_request(wire.set_velocity(left=0.3, right=0.3)))
        assert sink.writes == [] and session.robot.target_left == 0.0

    run_loop(main())
