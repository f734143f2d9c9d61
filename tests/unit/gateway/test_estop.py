"""What a payload on the e-stop keys means (:func:`read_estop`), alone and through the core on a fake clock."""

from __future__ import annotations

import pytest
from helpers import TRUE_ESTOPS

from blackmetal.gateway.estop import RELEASE_HINT, read_estop
from blackmetal.schemas import ErrorReport

from .test_core import Bench


@pytest.mark.parametrize("payload", TRUE_ESTOPS)
def test_a_true_meaning_engages_quietly(payload: bytes) -> None:
    estop = read_estop(payload)
    assert estop.engaged and estop.complaint is None and not estop.release_key


def test_the_one_release_releases_and_keeps_its_excerpt_only_off_the_release_key() -> None:
    assert read_estop(b'{"engaged": false}', release_key=True) == read_estop(b' {"engaged":false}\n', release_key=True)
    on_release = read_estop(b'{"engaged": false}', release_key=True)
    assert not on_release.engaged and on_release.snippet == "" and on_release.release_key
    on_estop = read_estop(b'{"engaged": false}')
    assert not on_estop.engaged and on_estop.snippet != ""


@pytest.mark.parametrize(("payload", "says"), [(b'{"data": false}', "is not a valid release"), (b"{", "unreadable payload")])
def test_anything_else_engages_and_says_why(payload: bytes, says: str) -> None:
    estop = read_estop(payload, release_key=True)
    assert estop.engaged and estop.complaint is not None and says in estop.complaint and RELEASE_HINT in estop.complaint


@pytest.mark.parametrize(
    "payload",
    TRUE_ESTOPS,
)
def test_any_true_meaning_engages_the_stop_without_complaint(payload: bytes) -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.2}}')
    bench.conn.on_estop(read_estop(payload), bench.t)
    bench.settle()
    assert bench.conn.health(bench.t).estop and bench.robot.counters["emergency_stops"] == 1
    assert not bench.of(ErrorReport)


@pytest.mark.parametrize("payload", [b"garbage", b"", b"{", b'{"data": false}', b'{"engaged": false, "why": "x"}', b"\xff" * 70000])
def test_anything_but_a_valid_release_engages_and_is_reported(payload: bytes) -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.2}}')
    bench.conn.on_estop(read_estop(payload), bench.t)
    bench.settle()
    assert bench.conn.health(bench.t).estop and bench.robot.counters["emergency_stops"] == 1
    (report,) = bench.of(ErrorReport)
    assert 'only {"engaged": false} releases' in report.reason


def test_only_a_valid_release_releases() -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.conn.on_estop(read_estop(b'{"engaged": true}'), bench.t)
    bench.settle()
    bench.conn.on_estop(read_estop(b' {"engaged":false}\n', release_key=True), bench.t)
    bench.settle()
    assert not bench.conn.health(bench.t).estop
