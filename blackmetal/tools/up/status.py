"""What up prints: how to drive the robot (or the fleet), then one live status line.

The subscriptions only store; the line is built when printed, on up's main thread.
"""

from __future__ import annotations

import functools
import math
import statistics
import time
from typing import Any

import zenoh

from blackmetal.runtime.fleet import FleetRobot
from blackmetal.runtime.zenoh_entities import undeclare
from blackmetal.schemas import ANY_GATEWAY_ALIVE, DEFAULT_PREFIX, ErrorReport, GatewayHealth, Keys, Pose

from ..client import Latest, decoded

#: The status line says the fleet is behind when its median poll rate is below this fraction of the asked rate.
BEHIND_RATIO = 0.9
#: A fleet robot's health older than this (s; the gateway reports every second) counts as missing.
HEALTH_STALE_S = 3.0
#: The fleet's pose rates are measured over one status interval this often (s).
POSE_SAMPLE_EVERY_S = 5.0
#: A robot's poses per second at most (a pose per poll; the gateway polls at most 200 Hz): the sampling ring's size.
POSES_PER_S_AT_MOST = 200
#: The fleet status line names at most this many robots per item, then "+k".
NAMED_AT_MOST = 5


def python_snippet(keys: Keys, endpoint: str) -> str:
    """A shell command that drives the robot for 3 s from plain Python (no single quotes inside)."""
    code = (
        "import zenoh, time; c = zenoh.Config(); "
        f'c.insert_json5("connect/endpoints", "[\\"{endpoint}\\"]"); s = zenoh.open(c); '
        f'[(s.put("{keys.cmd_vel}", "{{\\"linear\\":{{\\"x\\":0.2}},\\"angular\\":{{\\"z\\":0.5}}}}"), time.sleep(0.1)) '
        "for _ in range(30)]; s.close()"
    )
    return f"python3 -c '{code}'"


def _timeout_advice(cmd_timeout: float) -> str:
    """How often a client must publish, given the gateway's command timeout (s; 0: none)."""
    if not cmd_timeout > 0:
        return "commands never time out: publish a zero to stop"
    return f"commands time out after {cmd_timeout:g} s: publish at {math.ceil(2.5 / cmd_timeout):g} Hz or more"


def drive_help(keys: Keys, endpoint: str, cmd_timeout: float = 0.5) -> str:
    return "\n".join(
        [
            f"Drive it from any Zenoh client ({_timeout_advice(cmd_timeout)}):",
            f"  blackmetal teleop -e {endpoint}",
            f"  {python_snippet(keys, endpoint)}",
            f'  z_put -e {endpoint} -k {keys.cmd_vel} -p \'{{"linear":{{"x":0.2}}}}\'   # zenoh\'s own CLI, if installed',
            f"Watch it:  blackmetal watch -e {endpoint}    Pose:  z_get -e {endpoint} -s {keys.pose}",
            "Ctrl-C stops everything.",
        ]
    )


def goto_help(keys: Keys, endpoint: str) -> str:
    """How to send the robot somewhere: the navigation service (``blackmetal nav``) is one of up's processes."""
    return "\n".join(
        [
            f"Send it somewhere (the navigation service, {keys.nav_goal}):",
            f"  blackmetal goto 0.5 0.3 90 -e {endpoint}{'' if keys.prefix == DEFAULT_PREFIX else f' --prefix {keys.prefix}'}"
            "    # x, y in metres, heading in degrees; Ctrl-C cancels",
        ]
    )


class StatusLine:
    """Subscriptions for the live one-line status."""

    def __init__(self, session: zenoh.Session, keys: Keys, with_truth: bool) -> None:
        self.health = Latest(session, keys.health, GatewayHealth)
        self.pose = Latest(session, keys.pose, Pose)
        self.truth = Latest(session, keys.sim_truth, Pose) if with_truth else None
        self.errors = Latest(session, keys.errors, ErrorReport)
        self._last_count = 0
        self._last_time = time.monotonic()

    def render(self) -> str:
        now = time.monotonic()
        rate = (self.pose.count - self._last_count) / max(now - self._last_time, 1e-6)
        self._last_count, self._last_time = self.pose.count, now
        h: GatewayHealth | None = self.health.value
        parts = []
        if h is None:
            parts.append("gateway: waiting")
        else:
            parts.append(f"link {h.control.state}/{h.log.state}")
            reason = h.control.reason or h.log.reason  # why the robot cannot be reached, as the gateway knows it
            if reason and h.control.state != "connected":
                parts.append(reason)
            parts.append(f"poll {h.poll_hz:.0f} Hz")
            if h.estop:
                parts.append("E-STOP")
            if h.active_source:
                parts.append(f"{h.active_source} drives")
            elif h.cmd_timeout_active:
                parts.append("idle")
        p: Pose | None = self.pose.value
        if p is None:
            parts.append("pose: waiting")
        else:
            parts.append(f"pose x={p.x:+.3f} y={p.y:+.3f} yaw={math.degrees(p.yaw):+6.1f}° v={p.v:+.2f} w={p.w:+.2f}")
            parts.append(f"{rate:.0f} poses/s")
        if self.truth is not None and self.truth.value is not None:
            t: Pose = self.truth.value
            parts.append(f"truth x={t.x:+.3f} y={t.y:+.3f}")
        if self.errors.count:
            parts.append(f"errors {self.errors.count}")
        return " | ".join(parts)


def _named(ids: list[str]) -> str:
    """``r1, r3`` or, past NAMED_AT_MOST, ``r1, r2, r3, r4, r5 +7``."""
    shown = ", ".join(ids[:NAMED_AT_MOST])
    return shown + (f" +{len(ids) - NAMED_AT_MOST}" if len(ids) > NAMED_AT_MOST else "")


class PoseSampler:
    """Each robot's poses per second over one status interval every POSE_SAMPLE_EVERY_S: counting every pose
    cost more than the router's own work (0.1 cores at 100 robots)."""

    def __init__(self, session: zenoh.Session, prefixes: list[str], interval: float) -> None:
        self.session = session
        self.prefixes = set(prefixes)
        self.capacity = max(1024, math.ceil(POSES_PER_S_AT_MOST * len(prefixes) * interval * 1.5))
        self.rates: dict[str, float] | None = None  # None: not measured yet
        self._subscriber: Any = None
        self._since = 0.0
        self._next = time.monotonic()

    def tick(self, now: float) -> None:
        """At each status line: close an open window (its rates), or open one when due."""
        if self._subscriber is not None:
            counts = dict.fromkeys(self.prefixes, 0)
            while (sample := self._subscriber.try_recv()) is not None:
                if (prefix := str(sample.key_expr).removesuffix("/pose")) in counts:
                    counts[prefix] += 1
            undeclare(self._subscriber)
            self._subscriber = None
            elapsed = max(now - self._since, 1e-6)
            self.rates = {prefix: count / elapsed for prefix, count in counts.items()}
            self._next = now + POSE_SAMPLE_EVERY_S
        elif now >= self._next:
            self._subscriber = self.session.declare_subscriber("**/pose", zenoh.handlers.RingChannel(self.capacity))
            self._since = now


class FleetStatus:
    """Subscriptions for the fleet's one-line status; the callbacks only store, :meth:`render` does the arithmetic."""

    def __init__(self, session: zenoh.Session, robots: list[FleetRobot], interval: float = 2.0, poll_hz: float = 50.0) -> None:
        """``interval``: between two :meth:`render` calls (s); ``poll_hz``: the rate the gateways were asked for."""
        self.robots = robots
        self.poll_hz = poll_hz
        self.alive: set[str] = set()
        self.health: dict[str, tuple[GatewayHealth, float]] = {}
        self.errors = dict.fromkeys((r.prefix for r in robots), 0)
        self.poses = PoseSampler(session, [r.prefix for r in robots], interval)
        #: Robots seen with both links connected since the start: before that, a robot is "connecting", not "down".
        self._ever_linked: set[str] = set()
        self._subs: list[Any] = [session.liveliness().declare_subscriber(ANY_GATEWAY_ALIVE, self._on_token, history=True)]
        for prefix in self.errors:
            self._subs += [
                session.declare_subscriber(Keys(prefix).health, functools.partial(self._on_health, prefix)),
                session.declare_subscriber(Keys(prefix).errors, functools.partial(self._on_error, prefix)),
            ]

    def _on_token(self, sample: zenoh.Sample) -> None:
        if (prefix := Keys.prefix_of_gateway_token(str(sample.key_expr))) not in self.errors:  # not one of this fleet's
            return
        if sample.kind == zenoh.SampleKind.PUT:
            self.alive.add(prefix)
        else:
            self.alive.discard(prefix)

    def _on_health(self, prefix: str, sample: zenoh.Sample) -> None:
        if (health := decoded(GatewayHealth, sample)) is not None:  # else the previous one stands until it goes stale
            self.health[prefix] = (health, time.monotonic())

    def _on_error(self, prefix: str, _sample: zenoh.Sample) -> None:
        self.errors[prefix] += 1

    def render(self) -> str:
        now = time.monotonic()
        self.poses.tick(now)
        rates = None if self.poses.rates is None else [self.poses.rates[r.prefix] for r in self.robots]
        fresh = {p: h for p, (h, at) in list(self.health.items()) if now - at <= HEALTH_STALE_S}
        polls = [fresh[r.prefix].poll_hz if r.prefix in fresh else 0.0 for r in self.robots]
        count = len(self.robots)
        parts = [f"robots {len(self.alive)}/{count} up"]
        linked = {prefix for prefix, h in fresh.items() if h.control.state == h.log.state == "connected"}
        self._ever_linked |= linked
        # a robot not yet up since the start is connecting, no fault; one that was up and is not is missing or down
        connecting = [r.id for r in self.robots if r.prefix not in linked and r.prefix not in self._ever_linked]
        missing = [r.id for r in self.robots if r.prefix not in fresh and r.prefix in self._ever_linked]
        down = [r.id for r in self.robots if r.prefix in fresh and r.prefix not in linked and r.prefix in self._ever_linked]
        parts += [f"{label} {len(ids)}: {_named(ids)}" for label, ids in (("connecting", connecting), ("no health", missing)) if ids]
        if down:
            first = fresh[next(r.prefix for r in self.robots if r.id == down[0])]
            reason = first.control.reason or first.log.reason
            parts.append(f"link down {len(down)}: {_named(down)}" + (f" ({down[0]}: {reason})" if reason else ""))
        parts.append(f"poll min {min(polls):.0f} median {statistics.median(polls):.0f} Hz")
        linked_polls = [fresh[r.prefix].poll_hz for r in self.robots if r.prefix in linked]
        if linked_polls and statistics.median(linked_polls) < BEHIND_RATIO * self.poll_hz:
            parts.append(f"BEHIND {self.poll_hz:g} Hz: the host is short of CPU (commands and e-stops keep their latency)")
        parts.append("poses/s measuring" if rates is None else f"poses/s min {min(rates):.0f} median {statistics.median(rates):.0f}")
        stopped = [r.id for r in self.robots if r.prefix in fresh and fresh[r.prefix].estop]
        parts.append(f"E-STOP {len(stopped)}/{count}: {_named(stopped)}" if stopped else f"e-stop 0/{count}")
        driving = [f"{r.id} ({fresh[r.prefix].active_source})" for r in self.robots if r.prefix in fresh and fresh[r.prefix].active_source]
        if driving:
            parts.append(f"driving {_named(driving)}")
        if erring := [r.id for r in self.robots if self.errors[r.prefix]]:
            parts.append(f"errors {sum(self.errors.values())}: {_named(erring)}")
        return " | ".join(parts)


def fleet_drive_help(robots: list[FleetRobot], endpoint: str, cmd_timeout: float) -> str:
    first = robots[0].prefix
    return "\n".join(
        [
            f"Drive one robot from any Zenoh client, by its prefix ({first} ... {robots[-1].prefix}; {_timeout_advice(cmd_timeout)}):",
            f"  blackmetal teleop --prefix {first} -e {endpoint}",
            f"  {python_snippet(Keys(first), endpoint)}",
            f"Watch one:  blackmetal watch --prefix {first} -e {endpoint}    All:  blackmetal robots -e {endpoint}",
            f"Stop one:   blackmetal estop on --prefix {first} -e {endpoint}",
            f"Send one somewhere:  blackmetal goto 0.5 0.3 90 --prefix {first} -e {endpoint}    # m, m, degrees",
            "Ctrl-C stops everything.",
        ]
    )
