"""The robot's log port, sans I/O: a report that changes the state is published at once, a repeat at most
every STATUS_REPEAT_S, so a chattering robot cannot flood ``<prefix>/status``.
"""

from __future__ import annotations

from blackmetal.schemas import RobotStatus
from blackmetal.wire import LogReport, Malformed, ReplyDecoder

#: Log-port reports that repeat the last state are published at most this often (s).
STATUS_REPEAT_S = 0.9


class LogPort:
    def __init__(self) -> None:
        self.decoder = ReplyDecoder()
        self._last: RobotStatus | None = None

    def feed(self, data: bytes, wall: float) -> list[RobotStatus | Malformed]:
        """Statuses to publish and malformed input to report, in stream order; ``wall`` stamps the statuses."""
        out: list[RobotStatus | Malformed] = []
        for item in self.decoder.feed(data):
            if isinstance(item, Malformed):
                out.append(item)
            elif not isinstance(item, LogReport):
                out.append(Malformed("unexpected message", repr(item).encode()))
            else:
                status = RobotStatus.from_codes(wall, item.state, item.direction)
                last = self._last
                if last is None or (status.state, status.direction) != (last.state, last.direction) or wall - last.stamp >= STATUS_REPEAT_S:
                    out.append(status)
                    self._last = status
        return out
