"""Which impulse samples may be integrated, and over which interval: one rule set for live odometry and replay.

Every decision is made on typed values (:class:`EpochStart`, the interval, the count missed); an event's
text is for reports only, so rewording a message cannot change what is counted or integrated.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from .errors import SampleRejected, UnstampedSample

#: Samples may claim at most this much more time than their arrivals show, in total over an epoch (s).
SPACING_TOLERANCE_S = 0.1
#: How far the receiver's estimate of the smallest delivery delay may settle below the first sample's (s).
SETTLE_S = 0.5
#: Impulses from another gateway are taken over only after the followed one was silent this long (s).
FOLLOW_TIMEOUT_S = 1.0
#: Every sample rejected by the arrival check for this long, all the same distance ahead: the epoch's
#: measure of the delivery delay came from a late sample, and a new epoch starts from the punctual ones (s).
RESYNC_S = 1.0


def gap_event(dt: float, seq: int, max_gap: float) -> str:
    """The report of a gap not integrated across (one wording for live odometry and replay)."""
    return f"gap of {dt:.3f} s before seq {seq} exceeds {max_gap} s: not integrated"


def unstamped_reason(mono: float | None, source: str | None) -> str:
    """The report of a live sample without ``mono`` and/or ``source``: what is missing and what to upgrade."""
    missing = " and ".join(name for name, value in (("mono", mono), ("source", source)) if value is None)
    return (
        f"impulses without {missing}: the sender is a gateway older than this odometry or a foreign publisher; "
        "live odometry needs a gateway that stamps mono and source (upgrade the gateway; logs without them still replay)"
    )


class EpochStart(enum.Enum):
    """Why a sample starts a new epoch: it is not integrated from the previous one."""

    FIRST = "first"  # since the start or a reset
    GAP = "gap"  # longer than ``max_gap``
    #: Another gateway (a new ``source``) took over from a silent one.
    GATEWAY_RESTART = "gateway restart"
    #: A log without sources: the sequence went back while the stamps moved on.
    SEQUENCE_RESTART = "sequence restart"
    #: The epoch's delivery-delay measure came from a late sample: the steady samples after it start over.
    RESYNC = "resync"

    @property
    def restart(self) -> bool:
        return self is EpochStart.GATEWAY_RESTART or self is EpochStart.SEQUENCE_RESTART


@dataclass(frozen=True, slots=True)
class Verdict:
    start: EpochStart | None  # None: the epoch goes on, integrated over ``dt``
    dt: float  # s since the previous sample (0 for a new epoch)
    missed: int = 0  # samples numbered between the previous one and this one that never arrived
    event: str | None = None  # the text of a report, never decided on

    @property
    def new_epoch(self) -> bool:
        return self.start is not None


@dataclass(slots=True)
class EpochTally:
    """Gaps, restarts and missed samples from verdicts' kinds: the one count for live odometry and replay."""

    gaps: int = 0
    restarts: int = 0
    missed: int = 0

    def count(self, verdict: Verdict) -> None:
        if verdict.start is EpochStart.GAP:
            self.gaps += 1
        elif verdict.start is not None and verdict.start.restart:
            self.restarts += 1
        self.missed += verdict.missed


@dataclass(slots=True)
class SampleOrder:
    """Accepts or rejects impulse samples one by one (docs/commands/odometry.md, "Input with integrity").

    ``arrival - mono`` is the delivery delay plus a constant: it falls more than SPACING_TOLERANCE_S below its
    smallest value only when samples claim time that did not pass. ``live`` requires ``mono`` and ``source``.
    """

    max_gap: float
    live: bool
    seq: int | None = None
    time: float | None = None
    source: str | None = None
    arrival: float | None = None
    #: arrival - time of this epoch's first sample, and the smallest since (delivery delay plus a constant).
    first_offset: float | None = None
    least_offset: float | None = None
    #: The current run of samples rejected by the arrival check: the first one's arrival, and their offsets' range.
    ahead_since: float | None = None
    ahead_range: tuple[float, float] = (0.0, 0.0)

    def check(self, seq: int, stamp: float, mono: float | None, source: str | None, arrival: float | None) -> Verdict:
        """Accept (and remember) the sample, or raise SampleRejected and remember only the run of rejections it extends;
        ValueError if ``live`` and ``arrival`` is None (a caller's bug)."""
        if self.live:
            if arrival is None:
                raise ValueError("live impulse samples need their arrival time")
            if mono is None or source is None:
                raise UnstampedSample(unstamped_reason(mono, source))
        time = stamp if mono is None else mono
        if mono is None:
            arrival = None  # wall stamps may step: arrivals are compared with the gateway's monotonic time only
        if self.seq is None or self.time is None:
            return self._accept(seq, time, source, arrival, Verdict(EpochStart.FIRST, 0.0))
        if source != self.source:
            silent = arrival is None or self.arrival is None or arrival - self.arrival >= FOLLOW_TIMEOUT_S
            if not silent:
                raise SampleRejected(
                    f"impulses from gateway {source} while following gateway {self.source}: "
                    "two gateways publish on this prefix; only one is integrated"
                )
            if source is not None and self.source is not None:  # always, live
                event = f"gateway {source} took over from gateway {self.source} (a restart): not integrating across it"
                return self._accept(seq, time, source, arrival, Verdict(EpochStart.GATEWAY_RESTART, 0.0, event=event))
        if seq <= self.seq:
            if source is None and time > self.time:  # a log without sources (never live): a later stamp means a restart
                event = f"sequence restarted at {seq} after {self.seq} (gateway restart): not integrating across it"
                return self._accept(seq, time, source, arrival, Verdict(EpochStart.SEQUENCE_RESTART, 0.0, event=event))
            raise SampleRejected(f"duplicate or out-of-order sample: seq {seq} after seq {self.seq} from the same gateway")
        if time < self.time:
            clock = "stamp" if mono is None else "monotonic time"
            raise SampleRejected(f"{clock} went backwards: seq {seq} at {time:.6f} after seq {self.seq} at {self.time:.6f}")
        dt = time - self.time
        missed = seq - self.seq - 1
        if arrival is not None and self.least_offset is not None and arrival - time < self.least_offset - SPACING_TOLERANCE_S:
            ahead = self.least_offset - (arrival - time)
            if self._steadily_ahead(arrival, arrival - time):
                event = (
                    f"every sample for {RESYNC_S:g} s arrived {ahead:.3f} s earlier than the epoch's first one showed "
                    "(it came late): the delivery delay is measured again from these, not integrated across"
                )
                return self._accept(seq, time, source, arrival, Verdict(EpochStart.RESYNC, 0.0, event=event))
            raise SampleRejected(
                f"seq {seq} claims {dt:.3f} s since the previous sample, {ahead:.3f} s more than the samples' arrivals allow"
            )
        if dt > self.max_gap:
            return self._accept(seq, time, source, arrival, Verdict(EpochStart.GAP, 0.0, missed, gap_event(dt, seq, self.max_gap)))
        return self._accept(seq, time, source, arrival, Verdict(None, dt, missed))

    def _steadily_ahead(self, arrival: float, offset: float) -> bool:
        """Whether the run of arrival-check rejections this one extends has lasted RESYNC_S at one steady offset;
        an accepted sample ends the run (a forger's never grows while the followed gateway's pass)."""
        low, high = self.ahead_range
        if self.ahead_since is None or max(high, offset) - min(low, offset) > SPACING_TOLERANCE_S:
            self.ahead_since, self.ahead_range = arrival, (offset, offset)
            return False
        self.ahead_range = (min(low, offset), max(high, offset))
        return arrival - self.ahead_since >= RESYNC_S

    def _accept(self, seq: int, time: float, source: str | None, arrival: float | None, verdict: Verdict) -> Verdict:
        self.seq, self.time, self.source, self.arrival = seq, time, source, arrival
        self.ahead_since = None
        if arrival is None:
            self.first_offset = self.least_offset = None
        elif self.first_offset is None or self.least_offset is None or (verdict.new_epoch and verdict.start is not EpochStart.GAP):
            # a new pair of clocks. A gap keeps the pair and what it learnt: a late sample after a stall (a backlog)
            # must not become the measure every punctual sample after it fails
            self.first_offset = self.least_offset = arrival - time
        else:  # the smallest delivery delay seen, allowed to settle at most SETTLE_S below the first sample's
            self.least_offset = max(min(self.least_offset, arrival - time), self.first_offset - SETTLE_S)
        return verdict

    def forget(self) -> None:
        """Start over (a reset): the next sample is the first of an epoch; ``live`` stays."""
        self.seq = self.time = self.source = self.arrival = self.first_offset = self.least_offset = self.ahead_since = None
