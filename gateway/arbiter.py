"""Which commander drives: named command sources with priorities, and locks, as twist_mux does it, sans I/O.

The rules are in docs/concepts.md "Several commanders". Commands of sources that do not drive are dropped quietly
and counted; the governor still applies the limits, the command timeout and the e-stop, above everything.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import Enum
from typing import Any

from blackmetal.schemas import ConfigError, SourceHealth, Sources, Twist

#: The source of plain ``<prefix>/cmd_vel``.
DEFAULT_SOURCE = Sources.DEFAULT
#: A source or lock name: one key chunk, no wildcards.
_NAME_FORBIDDEN = set("*$?#/ ")


@dataclass(frozen=True, slots=True)
class SourceSpec:
    """A configured command source: its name (the key chunk), priority 0-255 and timeout (s)."""

    name: str
    priority: int
    timeout: float = 0.5


@dataclass(frozen=True, slots=True)
class LockSpec:
    """A configured lock: its name, the priority up to which it blocks, and an optional heartbeat timeout (s)."""

    name: str
    priority: int
    timeout: float | None = None


#: The sources a gateway knows unless its settings say otherwise (twist_mux-like priorities).
DEFAULT_SOURCES: tuple[SourceSpec, ...] = (
    SourceSpec(Sources.TELEOP, 100),
    SourceSpec(Sources.FOXGLOVE, 90),
    SourceSpec(Sources.DEFAULT, 50),
    SourceSpec(Sources.ROS2, 50),
    SourceSpec(Sources.NAV, 10),
)


def check_specs(sources: tuple[SourceSpec, ...], locks: tuple[LockSpec, ...]) -> None:
    """ConfigError naming the first source or lock that cannot work."""
    if not sources:
        raise ConfigError("at least one command source must be configured (e.g. the source 'default')")
    for kind, specs in (("source", sources), ("lock", locks)):
        names = [spec.name for spec in specs]
        for spec in specs:
            if not spec.name or _NAME_FORBIDDEN & set(spec.name) or spec.name.startswith("@"):
                raise ConfigError(f"{kind} name {spec.name!r} must be one key chunk: no '/', spaces, wildcards or leading '@'")
            if names.count(spec.name) > 1:
                raise ConfigError(f"{kind} {spec.name!r} is configured twice")
            if isinstance(spec.priority, bool) or not isinstance(spec.priority, int) or not 0 <= spec.priority <= 255:
                raise ConfigError(f"{kind} {spec.name!r}: priority must be an integer 0-255, got {spec.priority!r}")
            timeout = spec.timeout
            if timeout is not None and (not isinstance(timeout, (int, float)) or not math.isfinite(timeout) or timeout <= 0):
                raise ConfigError(f"{kind} {spec.name!r}: timeout must be a positive number of seconds, got {timeout!r}")


def _parse(kind: str, text: str) -> tuple[str, int, float | None]:
    parts = str(text).split(":")
    example = f"{kind} {'teleop:100:0.5' if kind == 'source' else 'supervisor:200:0.3'}"
    if not 2 <= len(parts) <= 3:
        raise ConfigError(f"{kind} {text!r} must be NAME:PRIORITY or NAME:PRIORITY:TIMEOUT, e.g. {example}")
    try:
        priority = int(parts[1])
        timeout = float(parts[2]) if len(parts) == 3 else None
    except ValueError:
        raise ConfigError(f"{kind} {text!r}: the priority must be an integer and the timeout a number, e.g. {example}") from None
    return parts[0], priority, timeout


def arbiter_of(sources: list[str], locks: list[str]) -> Arbiter:
    """The arbiter of the settings' ``NAME:PRIORITY[:TIMEOUT]`` sources (0.5 s if left out) and locks (none then)."""
    source_specs = [
        SourceSpec(name, priority, 0.5 if timeout is None else timeout)
        for name, priority, timeout in (_parse("source", s) for s in sources)
    ]
    return Arbiter(tuple(source_specs), tuple(LockSpec(*_parse("lock", text)) for text in locks))


class Admission(Enum):
    """What became of one command offered to the arbiter."""

    DRIVES = "drives"  # its source is the active one: the command becomes the target
    DROPPED = "dropped"  # another source drives, or a lock blocks this one: counted, not reported
    UNKNOWN = "unknown"  # no such source is configured: refused and reported


@dataclass(slots=True)
class _Source:
    spec: SourceSpec
    heard_at: float = -math.inf
    twist: Twist | None = None
    dropped: int = 0
    superseded: int = 0
    #: When it falls silent, until :meth:`Arbiter.update` has seen that (then inf: no deadline of its own).
    due: float = math.inf

    def live(self, now: float) -> bool:
        # as its due is written, to the last bit: else a tick at the due would see it live and spend the due
        return now < self.heard_at + self.spec.timeout


@dataclass(slots=True)
class _Lock:
    spec: LockSpec
    locked: bool = False
    heard_at: float = -math.inf
    #: When its heartbeat is missed, until :meth:`Arbiter.update` has seen that.
    due: float = math.inf

    def engaged(self, now: float) -> bool:
        timeout = self.spec.timeout
        return self.locked or (timeout is not None and now >= self.heard_at + timeout)  # as its due is written


class Why(Enum):
    """Why the driver changed; the value is how ``<prefix>/gateway/driver`` says it."""

    OUTRANKS = "{source} outranks {previous}"  # a live source of higher priority (or the first one) spoke
    SILENT = "{previous} fell silent for {timeout} s: {source} drives"  # its timeout ran out
    LOCKED = "a lock blocks {previous}: {source} drives"
    UNLOCKED = "a lock released: {source} drives"  # or its heartbeat came back: a blocked source drives again


@dataclass(frozen=True, slots=True)
class NewDriver:
    """Who drives now (None: nobody) and with what command, who drove before and why; ``blocked``: a lock blocks every
    live source, so the robot must brake now (silence is the command timeout's)."""

    source: str | None
    twist: Twist | None
    heard_at: float
    previous: str | None
    why: Why
    blocked: bool = False


@dataclass(slots=True)
class Arbiter:
    sources: tuple[SourceSpec, ...] = DEFAULT_SOURCES
    locks: tuple[LockSpec, ...] = ()
    _sources: dict[str, _Source] = field(init=False)
    _locks: dict[str, _Lock] = field(init=False)
    #: The source that drives (None: nobody has since the start or the last change of driver to nobody).
    active: str | None = field(init=False, default=None)
    # The earliest due (None: to compute again): between dues only an input changes the winner, so ``update`` waits for either.
    _earliest: float | None = field(init=False, default=None)
    _reweigh: bool = field(init=False, default=True)

    def __post_init__(self) -> None:
        check_specs(self.sources, self.locks)
        self._sources = {spec.name: _Source(spec) for spec in self.sources}
        self._locks = {spec.name: _Lock(spec) for spec in self.locks}

    @property
    def names(self) -> list[str]:
        return list(self._sources)

    @property
    def lock_names(self) -> list[str]:
        return list(self._locks)

    def has_source(self, name: str) -> bool:
        return name in self._sources

    def offer(self, name: str, twist: Twist, now: float) -> Admission:
        source = self._sources.get(name)
        if source is None:
            return Admission.UNKNOWN
        source.heard_at, source.twist, source.due = now, twist, now + source.spec.timeout
        self._earliest = None
        self.active = self._winner(now)
        if self.active == name:
            return Admission.DRIVES
        source.dropped += 1
        return Admission.DROPPED

    def superseded(self, name: str, count: int) -> None:
        """``count`` commands of source ``name`` were replaced by newer ones before they reached the arbiter."""
        source = self._sources.get(name)
        if source is not None:
            source.superseded += count

    def set_lock(self, name: str, locked: bool, now: float) -> bool:
        """Lock ``name`` engaged or released (a refresh either way); False if no such lock is configured."""
        lock = self._locks.get(name)
        if lock is None:
            return False
        lock.locked, lock.heard_at = locked, now
        lock.due = math.inf if lock.spec.timeout is None else now + lock.spec.timeout
        self._earliest, self._reweigh = None, True
        return True

    def update(self, now: float) -> NewDriver | None:
        """The change of driver due at ``now`` (a source timed out, a lock engaged or released), if any."""
        if not self._reweigh and now < self.next_deadline():
            return None  # no source fell silent, no lock changed, no input since the last weighing: the same winner
        self._earliest, self._reweigh = None, False
        for item in self._timed():
            if now >= item.due:
                item.due = math.inf  # seen: its deadline is spent
        winner = self._winner(now)
        previous = self.active
        if winner == previous:
            return None
        self.active = winner
        if previous is not None and not self._sources[previous].live(now):
            why = Why.SILENT
        elif previous is not None and self._sources[previous].spec.priority <= self.lock_priority(now):
            why = Why.LOCKED
        else:
            why = Why.UNLOCKED
        if winner is None:
            blocked = any(s.live(now) for s in self._sources.values())
            return NewDriver(None, None, -math.inf, previous, why, blocked=blocked)
        source = self._sources[winner]
        return NewDriver(winner, source.twist, source.heard_at, previous, why)

    def retune(self, name: str, **change: Any) -> None:
        """A new ``priority`` or ``timeout`` for source ``name`` (a parameter set live); :meth:`update` weighs it at once."""
        source = self._sources[name]
        spec = replace(source.spec, **change)
        check_specs((spec,), ())
        source.spec = spec
        self.sources = tuple(spec if s.name == name else s for s in self.sources)
        if source.heard_at != -math.inf:  # it falls silent after its new timeout (a longer one may bring it back)
            source.due = source.heard_at + spec.timeout
        self._earliest, self._reweigh = None, True

    def priority_of(self, name: str) -> int:
        return self._sources[name].spec.priority

    def timeout_of(self, name: str) -> float:
        return self._sources[name].spec.timeout

    def next_deadline(self) -> float:
        """When :meth:`update` may next change the driver without a new input: a live source's or a lock's timeout."""
        earliest = self._earliest
        if earliest is None:  # after every command: a plain loop, no list nor generator on the command path
            earliest = math.inf
            for items in (self._sources, self._locks):
                for item in items.values():
                    if item.due < earliest:
                        earliest = item.due
            self._earliest = earliest
        return earliest

    def _timed(self) -> list[_Source | _Lock]:
        return [*self._sources.values(), *self._locks.values()]

    def lock_priority(self, now: float) -> int:
        """The highest priority an engaged lock blocks (-1: none engaged)."""
        return max((lock.spec.priority for lock in self._locks.values() if lock.engaged(now)), default=-1)

    def _winner(self, now: float) -> str | None:
        """The live source of the highest priority above every engaged lock, among equals the driver, else the latest
        (one pass and no lists: it runs twice for every command)."""
        blocked_up_to = self.lock_priority(now) if self._locks else -1
        best: _Source | None = None
        active_tied = False
        for source in self._sources.values():
            priority = source.spec.priority
            if priority <= blocked_up_to or now >= source.heard_at + source.spec.timeout:  # not live
                continue
            if best is None or priority > best.spec.priority:
                best, active_tied = source, source.spec.name == self.active
            elif priority == best.spec.priority:
                if source.spec.name == self.active:
                    active_tied = True
                if source.heard_at > best.heard_at:
                    best = source
        if best is None:
            return None
        if active_tied:
            return self.active  # no flapping between equals: the driver keeps control until it times out
        return best.spec.name

    def source_health(self, now: float) -> dict[str, SourceHealth]:
        """Per source: its priority, seconds since its last command (None: never heard), commands dropped and superseded."""
        return {
            name: SourceHealth(s.spec.priority, None if s.heard_at == -math.inf else round(now - s.heard_at, 3), s.dropped, s.superseded)
            for name, s in self._sources.items()
        }

    def lock_states(self, now: float) -> dict[str, bool]:
        return {name: lock.engaged(now) for name, lock in self._locks.items()}
