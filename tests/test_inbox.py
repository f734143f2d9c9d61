"""A busy loop takes inputs handed over from another thread between two steps of its own work.

Without it, asyncio runs a ``call_soon_threadsafe`` only after every callback
already due in this turn: a fleet host's e-stop waited behind a hundred
robots' timers. The early take is bounded: the e-stop channel whole, one
item of each other channel, so a flood cannot crowd the loop's own steps.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable

from blackmetal.runtime.edge import Intake
from blackmetal.runtime.host import DeadlineTimer
from blackmetal.runtime.inbox import LoopInbox

TIMERS = 40
STEP_S = 0.002
PUT_AT_TICK = 3


class BusyCore:
    """A core whose every tick is a step of work; the third tick's hands inputs over from another thread."""

    def __init__(self, ticks: list[int], put_inputs: Callable[[], None]) -> None:
        self.ticks, self.put_inputs, self.due = ticks, put_inputs, 0.0

    def tick(self, now: float) -> None:
        if self.due != float("inf"):
            self.ticks.append(len(self.ticks))
            if len(self.ticks) == PUT_AT_TICK:
                thread = threading.Thread(target=self.put_inputs)  # as a Zenoh thread does, while the loop works
                thread.start()
                thread.join()
            time.sleep(STEP_S)
        self.due = float("inf")

    def next_deadline(self) -> float:
        return self.due


def _ticks_at_handling(take_early: bool) -> dict[str, list[int]]:
    """Forty timers due in one turn; an e-stop and ten commands handed over during the third: ticks run before each was handled."""
    ticks: list[int] = []
    handled: dict[str, list[int]] = {"estop": [], "cmd_vel": []}

    async def main() -> None:
        loop = asyncio.get_running_loop()
        inbox = LoopInbox() if take_early else None  # no inbox: the plain hand-over, drained at the end of the turn
        handover = Intake(loop, inbox=inbox)
        estop = handover.channel("estop", lambda item: handled["estop"].append(len(ticks)), priority=2)
        cmd_vel = handover.channel("cmd_vel", lambda item: handled["cmd_vel"].append(len(ticks)), priority=1)

        def put_inputs() -> None:
            for i in range(10):
                cmd_vel(i)
            estop(b"stop")

        at = loop.time() + 0.05  # one instant for all: due in the same turn of the loop
        timers = []
        for _ in range(TIMERS):
            core = BusyCore(ticks, put_inputs)
            core.due = time.monotonic()
            timer = DeadlineTimer(core, inbox=inbox)
            timer._running = True
            timer._timer = loop.call_at(at, timer._fire)
            timers.append(timer)
        deadline = time.monotonic() + 30
        while (len(ticks) < TIMERS or len(handled["cmd_vel"]) < 10) and time.monotonic() < deadline:
            await asyncio.sleep(0.01)
        for timer in timers:
            timer.stop()

    asyncio.run(main())
    assert handled["estop"] and len(handled["cmd_vel"]) == 10, handled
    return handled


def test_an_estop_is_taken_at_the_next_step_not_after_the_turn() -> None:
    plain = _ticks_at_handling(take_early=False)
    early = _ticks_at_handling(take_early=True)
    assert plain["estop"][0] >= TIMERS // 2, plain  # the baseline this fixes: after the turn (all forty, on a quiet machine)
    assert early["estop"] == [PUT_AT_TICK], early


def test_other_channels_get_one_item_early_and_the_rest_at_the_end_of_the_turn() -> None:
    early = _ticks_at_handling(take_early=True)
    first, *rest = early["cmd_vel"]
    assert first == PUT_AT_TICK and len(set(rest)) == 1 and rest[0] >= TIMERS // 2, early
