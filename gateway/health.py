"""The gateway's counters and its health report, built from the core's parts.

Published every ``health_period`` seconds on ``<prefix>/gateway/health``,
at once after an e-stop, and answered to a ``get`` on the same key.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from schemas import GatewayHealth, SourceHealth

if TYPE_CHECKING:
    from .core import RobotConnection


@dataclass
class Counters:
    commands_sent: int = 0
    polls: int = 0
    polls_skipped: int = 0
    replies: int = 0
    full_buffer: int = 0
    full_buffer_retries: int = 0
    lost_replies: int = 0
    malformed_replies: int = 0
    rejected_inputs: int = 0
    keepalives: int = 0


def health_report(conn: "RobotConnection", now: float) -> GatewayHealth:
    """The connection's state at ``now``, as one health message; wheel speeds are (left, right) like every wheel pair."""
    c = conn.counters
    governor = conn.governor
    accepted = governor.accepted
    rtt = conn.last_rtt
    return GatewayHealth(
        stamp=conn.wallclock(),
        control=conn.links.control.health(),
        log=conn.links.log.health(),
        commands_sent=c.commands_sent,
        polls=c.polls,
        replies=c.replies,
        full_buffer=c.full_buffer,
        full_buffer_retries=c.full_buffer_retries,
        malformed_replies=c.malformed_replies,
        garbage_bytes=conn.garbage_bytes,
        rejected_inputs=c.rejected_inputs,
        keepalives=c.keepalives,
        lost_replies=c.lost_replies,
        polls_skipped=c.polls_skipped,
        estop=governor.estop,
        cmd_timeout_active=governor.link_up and governor.timed_out(now),
        cmd_timeout=governor.settings.cmd_timeout,
        last_rtt_ms=None if rtt is None else round(rtt * 1000, 3),
        poll_hz=round(conn.polls.rate(now), 2),
        wheel_speeds=(0.0, 0.0) if accepted is None else (accepted.left, accepted.right),
        source=conn.source,
        conflict_with=conn.conflict.with_whom(now),
        active_source=conn.arbiter.active,
        sources={
            name: SourceHealth(priority=spec.priority, age=age, dropped=dropped)
            for spec, (name, (age, dropped)) in zip(conn.arbiter.sources, conn.arbiter.source_ages(now).items(), strict=True)
        },
        locks=conn.arbiter.lock_states(now),
    )
