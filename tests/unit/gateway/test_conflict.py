"""Two gateways on one prefix: the pure :class:`GatewayConflict`, and both braking through the core on a fake clock."""

from __future__ import annotations

import pytest

from blackmetal.gateway.conflict import CONFLICT_HOLD_S, REMIND_S, UNNAMED_RUN, ConflictNews, GatewayConflict
from blackmetal.schemas import ErrorReport

from .test_core import Bench


def test_a_conflict_starts_once_reminds_and_resolves_after_the_hold() -> None:
    conflict = GatewayConflict("me", "robot")
    assert not conflict.seen("me", 0.0) and conflict.next_deadline() == float("inf")
    assert conflict.seen("other", 0.0) and not conflict.seen("other", 0.5)  # the same conflict goes on
    assert conflict.tick(0.5) is ConflictNews.REMIND and conflict.tick(0.6) is None
    assert conflict.next_deadline() == 0.5 + REMIND_S
    assert conflict.with_whom(1.0) == "other" and "another gateway (run other) serves prefix robot" in conflict.reason()
    end = 0.5 + CONFLICT_HOLD_S
    assert conflict.tick(end) is ConflictNews.RESOLVED and conflict.with_whom(end) is None and conflict.tick(end) is None


def test_a_report_without_a_run_id_is_another_gateway() -> None:
    conflict = GatewayConflict("me", "robot")
    assert conflict.seen(None, 0.0) and conflict.other == UNNAMED_RUN
    assert "too old to name its run" in conflict.reason()


def test_a_second_gateway_on_the_prefix_brakes_both_until_one_leaves() -> None:
    from blackmetal.schemas import GatewayHealth

    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.3}}')
    other = bench.conn.health(bench.t)
    other = GatewayHealth(stamp=other.stamp, control=other.control, log=other.log, source="another-run")
    from blackmetal.schemas import encode

    for _ in range(3):  # its health arrives once a second
        bench.conn.on_health_seen(encode(other), bench.t)
        bench.settle()
        bench.run(1.0)
    bench.robot.advance(bench.t)
    assert not bench.robot.moving  # braked
    bench.cmd(b'{"linear":{"x":0.3}}')
    assert not bench.robot.moving  # and refuses commands, saying why
    reasons = [e.reason for e in bench.of(ErrorReport)]
    assert any("another gateway (run another-run)" in r for r in reasons)
    assert 3 <= sum("another gateway" in r and "serves prefix" in r for r in reasons) <= 8  # about once a second
    assert bench.conn.health(bench.t).conflict_with == "another-run"
    bench.run(4.0)  # the other one left
    assert any("commands accepted again" in r for r in [e.reason for e in bench.of(ErrorReport)])
    bench.cmd(b'{"linear":{"x":0.3}}')
    assert bench.robot.target_left == pytest.approx(0.3)
    own = encode(bench.conn.health(bench.t))
    bench.conn.on_health_seen(own, bench.t)  # its own reports are no conflict
    assert bench.conn.health(bench.t).conflict_with is None


def test_a_gateway_too_old_to_name_its_run_is_a_conflict_too() -> None:
    """A health without ``source`` on our prefix comes from another gateway: a missing field switches no check off."""
    from blackmetal.schemas import GatewayHealth, encode

    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.3}}')
    mine = bench.conn.health(bench.t)
    bench.conn.on_health_seen(encode(GatewayHealth(stamp=mine.stamp, control=mine.control, log=mine.log)), bench.t)
    bench.settle()
    bench.run(0.2)
    bench.robot.advance(bench.t)
    assert not bench.robot.moving
    assert any("too old to name its run" in e.reason and "upgrade it" in e.reason for e in bench.of(ErrorReport))
