"""Inputs waiting for a busy loop: the loop's own work takes them between two of its steps.

An input handed over from another thread (a Zenoh callback) schedules its
handling with ``call_soon_threadsafe``, which asyncio runs only after every
callback already queued for this turn of the loop. A fleet host's loop
turns through a hundred robots' poll replies and timers at a time, so an
e-stop for one robot waited behind up to a hundred others' work (1 ms
median, 12 ms at the 99th percentile at 100 robots). The loop's busy paths
(each timer fire, each read from a robot) call :meth:`LoopInbox.take_waiting`
after every step: whatever was handed over meanwhile is handled there, one
step of work later, not one turn later. The scheduled callback still runs
and finds nothing to do; correctness never depends on the early take.

A service makes one inbox for its loop and hands it to its hosts (their
timers and robot reads take from it) and to their hand-overs (which add to
it); a fleet host's robots share it, as they share the loop, so an e-stop
for one robot is taken between two other robots' steps. Nothing is global:
a hand-over given no inbox is drained at the end of the loop's turn only.

Call :meth:`LoopInbox.take_waiting` only from the loop's own work, never from
an input handler (that would handle inputs inside the handling of another).
"""

from __future__ import annotations

import asyncio
import weakref
from collections import deque
from collections.abc import Callable


class LoopInbox:
    """What is waiting for one loop: a ``take`` per hand-over that has inputs waiting."""

    def __init__(self) -> None:
        # weak: an entry must not keep its hand-over, and through it the loop, alive (the inboxes are keyed by loop)
        self._waiting: deque[weakref.WeakMethod[Callable[[], None]]] = deque()
        self._taking = False

    def add(self, take: weakref.WeakMethod[Callable[[], None]]) -> None:
        """Any thread: ``take`` handles what a hand-over holds; run it at the loop's next step.

        A weak reference made once by its owner (one per input, not one per sample: at 5,000
        samples a second a WeakMethod each cost the fleet odometry 0.05 cores).
        """
        self._waiting.append(take)

    def take_waiting(self) -> None:
        """The loop: handle what was handed over since the last step (``deque`` appends and pops are thread-safe)."""
        if not self._waiting or self._taking:
            return
        self._taking = True
        try:
            while self._waiting:
                take = self._waiting.popleft()()
                if take is None:
                    continue
                try:
                    take()
                except Exception as exc:  # the step that took it goes on; the loop's handler reports it
                    asyncio.get_running_loop().call_exception_handler({"message": "an input taken early failed", "exception": exc})
        finally:
            self._taking = False
