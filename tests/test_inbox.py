"""A busy loop takes inputs handed over from another thread between two steps of its own work.

Without it, asyncio runs a ``call_soon_threadsafe`` only after every callback
already due in this turn: a fleet host's e-stop waited behind a hundred
robots' timers.
"""

from __future__ import annotations

import asyncio
import threading
import time

from blackmetal.runtime.edge import Handover
from blackmetal.runtime.host import DeadlineTimer

TIMERS = 40
STEP_S = 0.003


class BusyCore:
    """A core whose every tick is a step of work (3 ms, the GIL released like a socket write's)."""

    def __init__(self, index: int, ticks: list[int], started: threading.Event) -> None:
        self.index, self.ticks, self.started, self.due = index, ticks, started, 0.0

    def tick(self, now: float) -> None:
        if self.due != float("inf"):
            self.ticks.append(self.index)
            if len(self.ticks) == 3:
                self.started.set()
            time.sleep(STEP_S)
        self.due = float("inf")

    def next_deadline(self) -> float:
        return self.due


def _tick_at_handling(take_early: bool) -> tuple[int, int]:
    """Forty timers due at once; an input put from a thread during the third: how many ticks ran before it was handled."""
    ticks: list[int] = []
    handled: list[int] = []
    started = threading.Event()

    async def main() -> None:
        loop = asyncio.get_running_loop()
        handover = Handover(loop)
        put = handover.channel("estop", lambda item: handled.append(len(ticks)), priority=2)
        if not take_early:
            handover._inbox.add = lambda take: None  # type: ignore[method-assign]  # the plain hand-over
        due = time.monotonic() + 0.05
        timers = []
        for i in range(TIMERS):
            core = BusyCore(i, ticks, started)
            core.due = due
            timers.append(DeadlineTimer(core))
        for timer in timers:
            timer._running = True
            timer._schedule(due)  # all due in the same turn of the loop
        thread = threading.Thread(target=lambda: (started.wait(5), put(b"stop")))
        thread.start()
        deadline = time.monotonic() + 30
        while (len(ticks) < TIMERS or not handled) and time.monotonic() < deadline:
            await asyncio.sleep(0.01)
        for timer in timers:
            timer.stop()
        thread.join()

    asyncio.run(main())
    assert handled, "the input was never handled"
    return handled[0], len(ticks)


def test_an_input_is_taken_at_the_next_step_not_after_the_turn() -> None:
    plain, total = _tick_at_handling(take_early=False)
    early, _ = _tick_at_handling(take_early=True)
    assert plain == total == TIMERS  # the baseline this fixes: after all forty
    assert early <= 5, f"handled after {early} of {TIMERS} ticks"
