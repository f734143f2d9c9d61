"""The gateway's counters, reported in its health."""

from __future__ import annotations

from dataclasses import dataclass


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
