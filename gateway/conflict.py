"""Two gateways on one prefix, sans I/O: noticed from each other's health reports (their run ids).

Both brake and refuse ``cmd_vel`` until the other has been silent for CONFLICT_HOLD_S, reminding on
``<prefix>/errors`` every REMIND_S meanwhile.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum, auto

#: A conflict holds this long after the other gateway's last health report (s).
CONFLICT_HOLD_S = 3.0
#: While it holds, the conflict is reported again this often (s).
REMIND_S = 1.0


class ConflictNews(Enum):
    REMIND = auto()  # the conflict holds: report it (again)
    RESOLVED = auto()  # the other gateway is gone


#: Stands for the run id of a gateway that published health without one (a version before run ids).
UNNAMED_RUN = "<no run id>"


@dataclass
class GatewayConflict:
    """Another gateway seen on this prefix: who, until when, and when to say so again."""

    own_source: str
    prefix: str
    #: The other gateway's run id while a conflict holds or is yet to be declared over.
    other: str | None = None
    _until: float = -math.inf
    _reminded: float = -math.inf

    def seen(self, source: str | None, now: float) -> bool:
        """A health report from run ``source`` at ``now``: True when it starts a conflict (brake at once). One without
        a run id is another gateway too (an older version, or a forger): a missing field must not switch the check off."""
        if source == self.own_source:
            return False
        new = now >= self._until
        if new:
            self._reminded = -math.inf
        self.other = UNNAMED_RUN if source is None else source
        self._until = now + CONFLICT_HOLD_S
        return new

    def active(self, now: float) -> bool:
        return now < self._until

    def with_whom(self, now: float) -> str | None:
        return self.other if self.active(now) else None

    def reason(self) -> str:
        if self.other == UNNAMED_RUN:
            return (
                f"another gateway serves prefix {self.prefix}, one too old to name its run (its health has no source): "
                "both brake and refuse cmd_vel until one leaves; upgrade it, or give one of them another --prefix"
            )
        return (
            f"another gateway (run {self.other}) serves prefix {self.prefix}: both brake and refuse cmd_vel "
            "until one leaves; give one of them another --prefix"
        )

    def tick(self, now: float) -> ConflictNews | None:
        if self.active(now):
            if now >= self._reminded + REMIND_S:
                self._reminded = now
                return ConflictNews.REMIND
            return None
        if self.other is not None:
            self.other = None
            return ConflictNews.RESOLVED
        return None

    def next_deadline(self) -> float:
        if self.other is None:
            return math.inf
        return min(self._until, self._reminded + REMIND_S)
