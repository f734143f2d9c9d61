"""What the gateway's clients ask of it through Zenoh, sans I/O: commands by source, locks, the e-stop, parameters.

A command is checked, weighed by the arbiter and handed to the governor; what goes to the robot because of it
is :class:`~blackmetal.gateway.core.GatewayCore`'s, which takes this class in.
"""

from __future__ import annotations

import secrets
from collections.abc import Callable
from typing import TYPE_CHECKING

from blackmetal.runtime.reports import ErrorReporter
from blackmetal.schemas import (
    DriverChange,
    ErrorReport,
    GatewayHealth,
    GatewayParams,
    Keys,
    Lock,
    ParamResult,
    ParamsSet,
    ParamsSetReply,
    PayloadError,
    RobotStatus,
    Twist,
    WheelImpulses,
    WheelPosition,
    decode,
    encode,
    excerpt,
)

from .arbiter import Admission, NewDriver, Why
from .conflict import ConflictNews, GatewayConflict
from .estop import EStopInput
from .health import Counters
from .latch import AT_START, Latch
from .links import DropLink
from .params import ParamTable
from .safety import Governor
from .settings import GatewaySettings

#: What the core produces besides bytes: messages to publish, and links to drop.
Event = WheelImpulses | WheelPosition | RobotStatus | GatewayHealth | ErrorReport | DriverChange | GatewayParams | DropLink


class ClientInputs:
    """The client side of :class:`~blackmetal.gateway.core.GatewayCore`, and the parts it shares with the robot's side."""

    def __init__(self, settings: GatewaySettings, now: float, wallclock: Callable[[], float], latch: Latch | None) -> None:
        self.settings = settings
        self.wallclock = wallclock
        self.keys = Keys(settings.prefix)
        self.counters = Counters()
        #: Names this run of the gateway in every impulse sample, so the odometry can tell a restart from a replay.
        self.run_token = secrets.token_hex(6)
        self.governor = Governor(settings.safety())
        self.latch = latch or Latch(False, wallclock(), AT_START)
        self.governor.on_estop(self.latch.engaged, now)
        #: A change of the latch for the host to save: an engage (already in force) or a release (in force once saved).
        self._latch_to_save: Latch | None = None
        self.conflict = GatewayConflict(self.run_token, self.keys.prefix)
        self.arbiter = settings.arbiter()
        self.params = ParamTable(settings, self.governor, self.arbiter)
        self._events: list[Event] = []
        #: An e-stop's health report, built only once the EMG_STOP bytes are taken.
        self._health_due: float | None = None
        self.reporter = ErrorReporter("gateway", self._events.append, wallclock=wallclock)

    if TYPE_CHECKING:  # the robot's side, in GatewayCore

        def _send_due(self, now: float) -> None: ...
        def health(self, now: float) -> GatewayHealth: ...

    def on_cmd_vel(self, source: str, payload: bytes, now: float) -> None:
        """A payload from command source ``source`` (``<prefix>/cmd_vel[/<source>]``): checked, arbitrated, sent or reported."""
        try:
            twist = decode(Twist, payload)
        except PayloadError as exc:
            self.reject(self.keys.cmd_vel_of(source), str(exc), now, exc.excerpt)
            return
        if not self.arbiter.has_source(source):
            reason = f"unknown command source {source!r}: the gateway's sources are {', '.join(self.arbiter.names)} (see --source)"
            self.reject(self.keys.cmd_vel_of(source), reason, now, excerpt(payload), family=self.keys.any_cmd_vel_source)
            return
        refusal = self.conflict.reason() if self.conflict.active(now) else self.governor.refusal(twist)
        if refusal is not None:
            self.reject(self.keys.cmd_vel_of(source), refusal, now, excerpt(payload))
            return
        self._arbitrate(now)  # a source that timed out hands over before the new command is weighed
        previous = self.arbiter.active
        admission = self.arbiter.offer(source, twist, now)
        if self.arbiter.active != previous:
            self._driver_changed(source, previous, Why.OUTRANKS)
        if admission is Admission.DRIVES:
            self._velocity_admitted(source, now)
            # checked above, and nothing since changed the e-stop, the link or the conflict: no second check on the path
            self.governor.steer(twist, now, now)
            self._send_due(now)

    def _velocity_admitted(self, source: str, now: float) -> None:
        """A velocity command of ``source`` drives now (a position move under way ends: MoveInputs)."""

    def on_superseded(self, source: str, count: int, now: float) -> None:
        """``count`` commands of ``source`` were replaced by newer ones before the gateway took them: counted and reported."""
        self.arbiter.superseded(source, count)
        self.reporter.report(
            self.keys.cmd_vel_of(source),
            f"{count} commands from source {source!r} were superseded by newer ones before the gateway took them: it publishes "
            "faster than the gateway takes commands (a commander needs 10-100 Hz; only its newest command counts)",
            now=now,
        )

    def on_lock(self, name: str, payload: bytes, now: float) -> None:
        """A payload on ``<prefix>/lock/<name>``: engages or releases (and refreshes) that lock, or is reported."""
        key = self.keys.lock_of(name)
        try:
            locked = decode(Lock, payload).locked
        except PayloadError as exc:  # not a refresh: a heartbeat lock times out and engages
            self.reject(key, f'{exc}; send {{"locked": true}} or {{"locked": false}}', now, exc.excerpt)
            return
        if not self.arbiter.set_lock(name, locked, now):
            known = ", ".join(self.arbiter.lock_names) or "none"
            reason = f"unknown lock {name!r}: the gateway's locks are {known} (see --lock)"
            self.reject(key, reason, now, excerpt(payload), family=self.keys.any_lock)
            return
        self._arbitrate(now)
        self._send_due(now)

    def _arbitrate(self, now: float) -> None:
        """Hand control over when the active source timed out, or a lock engaged or released."""
        change: NewDriver | None = self.arbiter.update(now)
        if change is None:
            return
        self._driver_changed(change.source, change.previous, change.why)
        if change.source is not None and change.twist is not None:  # through the acceleration limits, timed from its command
            self._drive(change.source, change.twist, change.heard_at, now, handed_over=True)
        elif change.blocked:
            self.governor.brake(now)  # a lock stops the robot now; silence is the command timeout's to brake

    def _drive(self, source: str, twist: Twist, heard_at: float, now: float, handed_over: bool = False) -> None:
        """The driving source's command goes to the governor, or its refusal is reported like any refused cmd_vel
        (one handed over from a source's past meets an e-stop, a dead link or a second gateway that came since)."""
        refusal = self.conflict.reason() if self.conflict.active(now) else self.governor.on_twist(twist, heard_at, now)
        if refusal is not None:
            reason = f"its last command, handed over to it, is refused: {refusal}" if handed_over else refusal
            self.reject(self.keys.cmd_vel_of(source), reason, now, excerpt(encode(twist)))

    def _driver_changed(self, source: str | None, previous: str | None, why: Why) -> None:
        """Publish who drives now, who drove before and why (``<prefix>/gateway/driver``)."""
        arbiter = self.arbiter

        def named(name: str | None) -> str:
            return "nobody" if name is None else f"{name} (priority {arbiter.priority_of(name)})"

        template = "{source} drives: nobody drove" if why is Why.OUTRANKS and previous is None else why.value
        timeout = None if previous is None else arbiter.timeout_of(previous)
        reason = template.format(source=named(source), previous=named(previous), timeout=timeout)
        self._events.append(DriverChange(stamp=self.wallclock(), source=source, previous=previous, reason=reason))

    def on_estop(self, estop: EStopInput, now: float) -> None:
        """A payload put on ``<prefix>/estop`` (or ``estop/release``): anything but a valid release engages.

        A release on ``estop`` is refused unless ``unsafe_release_on_estop``, and the stop stays as it is (a refused
        release must not engage a robot someone released properly meanwhile). An engage is in force at once and
        saved after its EMG_STOP is written; a release waits for its save (:meth:`latch_saved`)."""
        key = self.keys.estop_release if estop.release_key else self.keys.estop
        if estop.complaint is not None:
            self.reject(key, estop.complaint, now, estop.snippet)
        elif not estop.engaged and not estop.release_key and not self.settings.unsafe_release_on_estop:
            reason = (
                f'a release on {key} is refused: only {{"engaged": false}} put on {self.keys.estop_release} releases '
                "(a right the router may give to a safety role alone; `blackmetal estop off` puts there)"
            )
            self.reject(key, reason, now, estop.snippet)
            return
        if estop.engaged:
            self.governor.on_estop(True, now)
            if not self.latch.engaged:
                self.latch = Latch(True, self.wallclock(), key)
                self._latch_to_save = self.latch
            self._send_due(now)
        elif self.latch.engaged:
            self._latch_to_save = Latch(False, self.wallclock(), key)
            return  # released once saved: latch_saved
        else:
            self.governor.on_estop(False, now)  # released already: a fresh cmd_vel is needed to move, as after any release
        self._health_due = now  # built when the host takes the events, after it has written the EMG_STOP and saved it

    def take_latch(self) -> Latch | None:
        """A change of the e-stop latch to save now (after writing the outgoing bytes), or None."""
        latch, self._latch_to_save = self._latch_to_save, None
        return latch

    def latch_saved(self, latch: Latch, failure: str | None, now: float) -> None:
        """The host saved ``latch`` (``failure``: why it could not): a release takes effect now, or is refused."""
        key = latch.by
        if latch.engaged:
            if failure is not None:
                self.reporter.report(key, f"the e-stop is engaged, but {failure}: a restart of the gateway may release it", now=now)
            return
        if failure is not None:
            self.reject(key, f"the release is refused, the e-stop stays engaged: {failure}", now)
            return
        self.latch = latch
        self.governor.on_estop(False, now)
        self._send_due(now)
        self._health_due = now

    def started_engaged(self, reason: str, now: float) -> None:
        """Why the gateway started with its e-stop engaged, for ``<prefix>/errors``."""
        self.reporter.report(self.keys.estop, reason, by="gateway", now=now)

    def on_health_seen(self, payload: bytes, now: float) -> None:
        """A health report on our own key: one from another gateway run means two gateways share this prefix."""
        try:
            other = decode(GatewayHealth, payload).source
        except PayloadError:
            return
        if self.conflict.seen(other, now):  # a new conflict: stop driving at once
            self.governor.brake(now)
        if self.conflict.other is not None:
            self._conflict_news(self.conflict.tick(now), now)
            self._send_due(now)

    def _conflict_news(self, news: ConflictNews | None, now: float) -> None:
        if news is ConflictNews.REMIND:
            self.reporter.report(self.keys.health, self.conflict.reason(), by="gateway", now=now)
        elif news is ConflictNews.RESOLVED:
            self.reporter.report(self.keys.health, "the other gateway on this prefix is gone: commands accepted again", now=now)

    def on_params_set(self, payload: bytes, now: float) -> ParamsSetReply | str:
        """A :class:`ParamsSet`: each value set at once or refused and reported; the new table is published.
        A payload that is not a ParamsSet is reported, and why is returned for the edge to answer with."""
        key = self.keys.params_set
        try:
            values = decode(ParamsSet, payload).values
        except PayloadError as exc:
            why = f'{exc}; send {{"values": {{"max_wheel_speed": 0.3}}}}'
            self.reject(key, why, now, exc.excerpt)
            return why
        results = []
        for name, value in values.items():
            refused = self.params.set(name, value)
            results.append(ParamResult(name, refused is None, refused or ""))
            if refused is not None:
                self.reject(key, refused, now, family=key)
        changed = [r.name for r in results if r.successful]
        if changed:
            self._arbitrate(now)
            self._send_due(now)
            self._events.append(self.params_now(changed))
        return ParamsSetReply(results, self.params_now())

    def params_now(self, changed: list[str] | None = None) -> GatewayParams:
        """The parameter table with each value now (``changed``: the names a set just changed)."""
        return GatewayParams(stamp=self.wallclock(), params=self.params.table(), changed=changed or [])

    def note_input(self, key: str, reason: str, now: float) -> None:
        """Something about an input that its publisher should know (a flood began or ended): reported, not counted."""
        self.reporter.report(key, reason, now=now)

    def reject(self, key: str, reason: str, now: float, snippet: str = "", family: str | None = None) -> None:
        """An input refused: counted and reported on ``<prefix>/errors`` (rate-limited per key ``family``, default the key)."""
        self.counters.rejected_inputs += 1
        self.reporter.report(key, reason, snippet, now=now, family=family)
