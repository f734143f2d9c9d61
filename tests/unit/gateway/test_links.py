"""The robot's links as the core sees them: states, silence timers, reconnect pacing; alone and through the core."""

from __future__ import annotations

import math

from blackmetal.gateway.links import DropLink, Links, LinkStatus
from blackmetal.schemas import ErrorReport

from .test_core import Bench


def test_a_link_counts_its_reconnects_and_says_how_long_it_was_down() -> None:
    links = Links(silence_timeout=1.0, log_silence_timeout=3.5)
    links.connecting("control")
    assert links.control.status is LinkStatus.CONNECTING and not links.control.connected
    assert links.up("control", 0.0, wall=100.0) is None  # never up before
    assert links.down("control", 2.0, "reset") and links.control.health().reason == "reset"
    assert not links.down("control", 2.5, "refused")  # it was down already
    assert links.up("control", 4.0, wall=104.0) == 2.0
    assert links.control.health().reconnects == 1 and links.control.health().state == "connected"


def test_only_unanswered_requests_run_the_control_links_silence_clock() -> None:
    links = Links(silence_timeout=1.0, log_silence_timeout=3.5)
    links.up("control", 0.0, wall=0.0)
    assert links.next_deadline() == math.inf
    links.request_sent(1.0)
    links.request_sent(1.5)  # the clock runs from the first unanswered one
    assert links.next_deadline() == 2.0 and links.due(1.9) == []
    assert links.due(2.0) == [DropLink("control", "robot silent: no reply for 1 s")]
    links.received("control", 2.1)
    assert links.next_deadline() == math.inf


def test_the_log_link_is_dropped_after_its_silence() -> None:
    links = Links(silence_timeout=1.0, log_silence_timeout=3.5)
    links.up("log", 0.0, wall=0.0)
    assert links.next_deadline() == 3.5
    assert links.due(3.5) == [DropLink("log", "no state report for 3.5 s")]


def test_a_silent_robot_is_dropped_after_the_silence_timeout() -> None:
    bench = Bench(silence_timeout=0.5)
    bench.connect()
    bench.run(0.3)
    bench.answering = False
    bench.run(2.0)
    drops = bench.of(DropLink)
    assert drops and drops[0].link == "control" and "silent" in drops[0].reason
    assert all(d.link == "control" for d in drops)  # the log link is allowed 3.5 s
    bench.run(2.0)
    assert any(d.link == "log" for d in bench.of(DropLink))


def test_losing_and_regaining_the_log_link_is_reported() -> None:
    bench = Bench()
    bench.connect()
    bench.run(1.0)
    bench.conn.link_down("log", "closed by the robot", bench.t)
    bench.run(2.0)
    bench.conn.link_up("log", bench.t)
    bench.settle()
    reasons = [e.reason for e in bench.of(ErrorReport)]
    assert "log link down: closed by the robot" in reasons
    assert any(r.startswith("log link up again after 2.0 s") for r in reasons)


def test_reconnect_backoff_is_not_reset_by_connections_that_die_at_once() -> None:
    from blackmetal.gateway.links import ReconnectBackoff

    backoff, now, attempts = ReconnectBackoff(first=0.05, cap=2.0, stable=5.0), 0.0, 0
    while now < 10.0:  # a robot that accepts and closes at once, for 10 s
        backoff.opened(now)
        now += backoff.failed(now + 0.001) + 0.001
        attempts += 1
    assert attempts <= 10  # 0.05, 0.1, ... then 2 s apart (was 144-149 in 10 s)
    backoff.opened(now)
    assert backoff.failed(now + 6.0) == 0.05  # a connection that held 6 s starts the backoff over
