"""A fleet process's telemetry puts, held to the end of the loop's turn (1 ms at most) and then made back to back.

Puts made back to back leave Zenoh in a few batches instead of a wake-up and a write each (measured in
docs/performance.md, "Telemetry puts made back to back"). Only telemetry goes through a burst, and only on the loop: a
command, an e-stop, a health message or an error report is never held.
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import zenoh

log = logging.getLogger("blackmetal.burst")

#: The longest a put is held (s): past it, the puts held so far go at once, the next ones start a new burst. All of a
#: fleet's robots are polled on one grid, so their replies come in the same turn of the loop; held to its end, the first
#: robot's impulse waited for a hundred others' handling (2.9-4.0 ms at p50 instead of 0.4-0.5 at 100 robots). A
#: millisecond is some twenty robots' handling: batches still, and bounds what the first one waits.
MAX_HOLD_S = 0.001


class PutBurst:
    """Puts held until the loop's current turn ends (one ``call_soon`` per burst), or for ``max_hold`` seconds if that
    comes first, then made in the order they came.

    A robot's samples keep their order, per key. The delay is the rest of the loop's turn (the other robots whose input
    was ready at the same time), at most ``max_hold`` plus the handling of the one put that found it past.
    """

    def __init__(self, max_hold: float = MAX_HOLD_S) -> None:
        import zenoh

        self.max_hold = max_hold
        self._held: list[tuple[zenoh.Publisher, bytes, bytes | None]] = []
        self._since = 0.0
        self._error = zenoh.ZError
        #: Puts Zenoh refused, for a test or a look in a debugger (a robot's edge closed while its sample was held).
        self.refused = 0

    def put(self, publisher: "zenoh.Publisher", payload: bytes, attachment: bytes | None = None) -> None:
        """On the loop (a RuntimeError elsewhere, and nothing held): ``publisher.put(payload, attachment=...)`` once the
        loop's turn ends, or at once with the others held if the first of them has waited ``max_hold``."""
        loop = asyncio.get_running_loop()  # every time: a put off the loop raises, whatever is held
        held = self._held
        held.append((publisher, payload, attachment))
        if len(held) == 1:
            self._since = time.perf_counter()
            loop.call_soon(self.flush)
        elif time.perf_counter() - self._since >= self.max_hold:
            self.flush()  # the call_soon already scheduled finds the next burst, or nothing

    def flush(self) -> None:
        """Every held put, oldest first. A put Zenoh refuses (its robot's edge closed meanwhile: a restart, the end) is
        dropped, and the rest still go."""
        held, self._held = self._held, []
        error = self._error
        for publisher, payload, attachment in held:
            try:
                if attachment is None:
                    publisher.put(payload)
                else:
                    publisher.put(payload, attachment=attachment)
            except error as exc:  # expected at a restart or the end: the publisher went with its robot's edge
                self.refused += 1
                log.debug("a held put was refused: %s", exc)
            except Exception:  # a bug (a payload Zenoh cannot take): that one put is lost, not the others'
                self.refused += 1
                log.exception("a held put failed")

    def __len__(self) -> int:
        return len(self._held)
