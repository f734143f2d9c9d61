"""The robot's log port: a changed state at once, a repeat at most every STATUS_REPEAT_S, anything else handed back."""

from __future__ import annotations

from blackmetal import wire
from blackmetal.gateway.log_port import STATUS_REPEAT_S, LogPort
from blackmetal.schemas import RobotStatus
from blackmetal.wire import Malformed


def test_a_repeat_is_published_at_most_every_status_repeat_and_a_change_at_once() -> None:
    port = LogPort()
    report = wire.encode_log_report(1, 1)
    assert len(port.feed(report, 100.0)) == 1
    assert port.feed(report, 100.5) == []
    (again,) = port.feed(report, 100.0 + STATUS_REPEAT_S)
    assert isinstance(again, RobotStatus) and again.stamp == 100.0 + STATUS_REPEAT_S
    (changed,) = port.feed(wire.encode_log_report(2, 1), 100.0 + STATUS_REPEAT_S + 0.1)
    assert isinstance(changed, RobotStatus)


def test_anything_but_a_log_report_is_handed_back_malformed() -> None:
    port = LogPort()
    items = port.feed(wire.encode_status(wire.STATUS_FULL_BUFFER), 1.0)
    assert len(items) == 1 and isinstance(items[0], Malformed) and items[0].reason == "unexpected message"
