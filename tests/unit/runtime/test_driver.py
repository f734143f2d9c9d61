"""The service driver's one rule for the command path: only the thread that delivers a sample may take it directly.

``docs/threads.md`` states it: the loop drains, a pump only queues, and a
Zenoh delivery thread may run the core directly while the driver serves.
So at most two kinds of thread ever run a core, and the core lock is never
entered twice by one thread.
"""

from __future__ import annotations

import asyncio
import math
import threading
from typing import Any

import pytest

from blackmetal.runtime.driver import CoreLock, Driver, queue_only
from blackmetal.runtime.intake import Intake
from unit.gateway.test_direct_take import LoopThread


class Core:
    """A pure core that notes which thread ran each input."""

    def __init__(self) -> None:
        self.threads: list[str] = []

    def on_item(self, item: str, now: float) -> None:
        self.threads.append(threading.current_thread().name)

    def tick(self, now: float) -> None:
        pass

    def next_deadline(self) -> float:
        return math.inf


class Rig:
    """A driver serving on a loop thread, and one direct channel into its core."""

    def __init__(self, loop_thread: LoopThread) -> None:
        self.loop_thread = loop_thread
        self.core = Core()
        self.driver = Driver(self.core)
        driver = self.driver
        self.stop = loop_thread.call(asyncio.Event)

        async def serve() -> None:
            driver.open()
            await driver.serve(self.stop)

        self.task = asyncio.run_coroutine_threadsafe(serve(), loop_thread.loop)
        loop_thread.call(lambda: None)
        self.intake = Intake(loop_thread.loop, on_error=driver.fail, lock=driver.lock, after_drain=driver.publish)

        def take(item: tuple[str]) -> bool:
            return driver.may_take_directly() and driver.run_locked(self.core.on_item, *item) is None

        self.put = self.intake.channel("items", driver.handler(self.core.on_item), priority=1, direct=take)

    def taken_directly(self) -> int:
        return self.intake._channels[0].direct_taken

    def settle(self) -> None:
        self.loop_thread.call(lambda: None)
        self.loop_thread.call(lambda: None)

    def close(self) -> None:
        """Stop serving (again: nothing more happens)."""
        self.loop_thread.loop.call_soon_threadsafe(self.stop.set)
        self.task.result(10)


@pytest.fixture
def rig() -> Any:
    loop_thread = LoopThread()
    loop_thread.thread.name = "loop"
    running = Rig(loop_thread)
    yield running
    running.close()
    loop_thread.close()


def on_thread(name: str, fn: Any) -> None:
    thread = threading.Thread(target=fn, name=name)
    thread.start()
    thread.join(10)


def test_the_thread_that_delivers_a_sample_takes_it_directly(rig: Rig) -> None:
    on_thread("zenoh", lambda: rig.put(("a",)))
    assert rig.core.threads == ["zenoh"] and rig.taken_directly() == 1


def test_a_pump_only_queues_and_the_loop_runs_the_core(rig: Rig) -> None:
    def pump() -> None:
        queue_only()  # what every pump thread does first (blackmetal.runtime.flood)
        rig.put(("a",))

    on_thread("pump", pump)
    rig.settle()
    assert rig.core.threads == ["loop"] and rig.taken_directly() == 0


def test_the_loop_never_takes_directly(rig: Rig) -> None:
    rig.loop_thread.call(lambda: rig.put(("a",)))
    rig.settle()
    assert rig.core.threads == ["loop"] and rig.taken_directly() == 0


def test_before_the_driver_serves_and_after_it_stopped_every_input_waits_for_the_loop(rig: Rig) -> None:
    rig.close()
    on_thread("zenoh", lambda: rig.put(("a",)))
    rig.settle()
    assert rig.core.threads == ["loop"] and rig.taken_directly() == 0


def test_at_most_two_kinds_of_thread_run_a_core(rig: Rig) -> None:
    def pump() -> None:
        queue_only()
        for _ in range(50):
            rig.put(("p",))

    threads = [
        threading.Thread(target=lambda: [rig.put(("z",)) for _ in range(50)], name="zenoh"),
        threading.Thread(target=pump, name="pump"),
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(10)
    rig.settle()
    assert set(rig.core.threads) <= {"loop", "zenoh"}


def test_the_core_lock_is_never_reentered() -> None:
    lock = CoreLock()
    with lock:
        assert lock.held()
        with pytest.raises(RuntimeError, match="not re-entrant"), lock:
            pass
        assert not lock.acquire(blocking=False)  # tried (as a direct take does): refused, never a second hold
    assert not lock.held()


def on_another_thread(call: Any) -> Any:
    """``call``'s result, made on a thread of its own, as a Zenoh thread would make it."""
    result: list[Any] = []
    on_thread("zenoh", lambda: result.append(call()))
    return result[0]


def test_only_another_thread_may_take_directly_and_only_while_the_driver_serves() -> None:
    driver = Driver(Core())
    assert not driver.may_take_directly() and not on_another_thread(driver.may_take_directly), "not serving yet"

    async def serving() -> None:
        driver.open()  # on this thread: it is the loop's
        assert not driver.may_take_directly(), "the loop's own thread never takes directly"
        assert on_another_thread(driver.may_take_directly)
        driver.shut()
        assert not on_another_thread(driver.may_take_directly), "a stopped or failed driver leaves every input to its loop"

    asyncio.run(serving())


def test_scheduling_on_a_loop_that_closed_does_nothing_and_raises_nothing() -> None:
    driver, ran = Driver(Core()), []

    async def serving() -> None:
        driver.open()

    asyncio.run(serving())  # its loop is closed now
    on_another_thread(lambda: driver.schedule(lambda: ran.append(1)))
    assert ran == []
