"""Pairing replies with requests: what the core's congestion check relies on, over any order of events."""

from __future__ import annotations

from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from blackmetal.gateway.exchange import Exchange
from blackmetal.wire import CommandCode, SpeedReading, StatusReply, set_velocity, simple

_events = st.lists(
    st.one_of(
        st.tuples(st.just("poll"), st.floats(-0.05, 0.3)),  # a request; its time may even lie a little before the last one
        st.tuples(st.just("velocity"), st.floats(-0.05, 0.3)),
        st.tuples(st.just("status"), st.sampled_from(["RECIEVE_OK", "FULL_BUFFER"])),
        st.tuples(st.just("speed"), st.just(None)),
        st.tuples(st.just("expire"), st.floats(0.0, 2.0)),
        st.tuples(st.just("forget"), st.just(None)),
    ),
    max_size=60,
)


@given(_events)
def test_in_doubt_says_whether_any_outstanding_request_is_expired(events: list[tuple[str, Any]]) -> None:
    exchange = Exchange(reply_timeout=0.5, late_horizon=1.5)
    now = 0.0
    for kind, value in events:
        if kind in ("poll", "velocity"):
            request = simple(CommandCode.GET_LR_WHEEL_VELOCITY) if kind == "poll" else set_velocity(left=0.1, right=0.1)
            exchange.sent(request, now + value)
            now += max(value, 0.0)
        elif kind == "status":
            exchange.received(StatusReply(value), now)
        elif kind == "speed":
            exchange.received(SpeedReading(left=10, right=-10), now)
        elif kind == "expire":
            now += value
            exchange.expire(now)
        else:
            exchange.forget_expired()
        assert exchange.in_doubt == any(p.expired for p in exchange.outstanding)
