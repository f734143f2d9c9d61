"""The command arbiter on a fake clock: priorities, ties without flapping, timeouts, locks with and without heartbeats."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from blackmetal.gateway.arbiter import DEFAULT_SOURCES, Admission, Arbiter, LockSpec, SourceSpec
from blackmetal.schemas import ConfigError, SourceHealth, Twist, Vector3


def twist(v: float) -> Twist:
    return Twist(linear=Vector3(x=v))


def test_the_defaults_are_twist_mux_like() -> None:
    assert [(s.name, s.priority, s.timeout) for s in DEFAULT_SOURCES] == [
        ("teleop", 100, 0.5),
        ("foxglove", 90, 0.5),
        ("default", 50, 0.5),
        ("ros2", 50, 0.5),
        ("nav", 10, 0.5),
    ]
    assert Arbiter().lock_names == []


def test_the_highest_live_priority_drives_and_the_others_are_dropped_and_counted() -> None:
    arb = Arbiter()
    assert arb.offer("nav", twist(0.3), 0.0) is Admission.DRIVES
    assert arb.offer("teleop", twist(0.0), 0.05) is Admission.DRIVES  # the operator takes over at once
    for k in range(1, 10):
        assert arb.offer("nav", twist(0.3), 0.05 + 0.05 * k) is Admission.DROPPED
        assert arb.offer("teleop", twist(0.0), 0.06 + 0.05 * k) is Admission.DRIVES
    ages = arb.source_health(0.6)
    assert (ages["nav"].age, ages["nav"].dropped, ages["nav"].superseded) == (pytest.approx(0.1), 9, 0)
    assert ages["teleop"].dropped == 0 and ages["foxglove"] == SourceHealth(90, None, 0, 0)
    assert arb.active == "teleop"


def test_a_tie_keeps_the_driver_until_it_times_out() -> None:
    arb = Arbiter()
    assert arb.offer("default", twist(0.1), 0.0) is Admission.DRIVES
    for t in (0.1, 0.2, 0.3, 0.4):  # ros2 has the same priority: it waits, however often it publishes
        assert arb.offer("ros2", twist(0.2), t) is Admission.DROPPED
        assert arb.offer("default", twist(0.1), t + 0.01) is Admission.DRIVES
    assert arb.offer("ros2", twist(0.25), 0.45) is Admission.DROPPED
    assert arb.update(0.9) is None  # default heard at 0.41: live until 0.91
    change = arb.update(0.91)
    assert change is not None and change.source == "ros2" and change.twist == twist(0.25) and change.heard_at == 0.45
    assert arb.offer("default", twist(0.1), 0.94) is Admission.DROPPED  # now ros2 (live until 0.95) keeps it, equally


def test_when_the_driver_falls_silent_the_next_live_source_takes_over_on_its_deadline() -> None:
    arb = Arbiter()
    arb.offer("nav", twist(0.3), 0.0)
    arb.offer("teleop", twist(0.0), 0.0)
    arb.offer("nav", twist(0.3), 0.3)
    assert arb.next_deadline() == 0.5  # teleop's timeout
    change = arb.update(0.5)
    assert change is not None and (change.source, change.twist, change.blocked) == ("nav", twist(0.3), False)
    assert arb.next_deadline() == pytest.approx(0.8)
    last = arb.update(0.8)
    assert last is not None and last.source is None and not last.blocked  # nobody live: the command timeout brakes
    assert arb.next_deadline() == math.inf  # nothing more will change without a new input
    assert arb.update(5.0) is None


def test_an_unknown_source_is_refused() -> None:
    arb = Arbiter()
    assert arb.offer("joystick", twist(0.1), 0.0) is Admission.UNKNOWN
    assert arb.active is None and "joystick" not in arb.source_health(0.0)


def test_an_engaged_lock_blocks_equal_and_lower_priorities_until_released() -> None:
    arb = Arbiter(locks=(LockSpec("pause", 50),))
    assert arb.lock_states(0.0) == {"pause": False}
    arb.offer("default", twist(0.2), 0.0)
    assert arb.set_lock("pause", True, 0.1)
    change = arb.update(0.1)
    assert change is not None and change.source is None and change.blocked  # the robot must brake now
    assert arb.offer("default", twist(0.2), 0.2) is Admission.DROPPED  # equal priority: blocked
    assert arb.offer("nav", twist(0.2), 0.2) is Admission.DROPPED  # lower: blocked
    assert arb.offer("foxglove", twist(0.1), 0.25) is Admission.DRIVES  # higher: drives through the lock
    assert arb.set_lock("pause", False, 0.3) and arb.lock_states(0.3) == {"pause": False}
    assert not arb.set_lock("nosuchlock", True, 0.3)


def test_a_heartbeat_lock_is_engaged_until_refreshed_and_again_when_its_supervisor_dies() -> None:
    arb = Arbiter(locks=(LockSpec("supervisor", 255, timeout=0.2),))
    assert arb.lock_states(0.0) == {"supervisor": True}  # no heartbeat yet: nothing moves
    assert arb.offer("teleop", twist(0.1), 0.0) is Admission.DROPPED
    arb.set_lock("supervisor", False, 0.05)
    assert arb.offer("teleop", twist(0.1), 0.06) is Admission.DRIVES
    for t in (0.15, 0.25):
        arb.set_lock("supervisor", False, t)
        arb.offer("teleop", twist(0.1), t)
    assert arb.next_deadline() == pytest.approx(0.45)  # the heartbeat is due by then
    assert arb.update(0.44) is None
    change = arb.update(0.45)
    assert change is not None and change.source is None and change.blocked


def test_lock_priority_and_a_higher_source_drive_through() -> None:
    arb = Arbiter(locks=(LockSpec("low", 10), LockSpec("mid", 60)))
    arb.set_lock("low", True, 0.0)
    arb.set_lock("mid", True, 0.0)
    assert arb.lock_priority(0.0) == 60
    arb.set_lock("mid", False, 0.1)
    assert arb.lock_priority(0.1) == 10
    assert arb.offer("nav", twist(0.1), 0.1) is Admission.DROPPED and arb.offer("ros2", twist(0.1), 0.1) is Admission.DRIVES


@pytest.mark.parametrize(
    ("sources", "locks", "match"),
    [
        ((), (), "at least one"),
        ((SourceSpec("a", 1), SourceSpec("a", 2)), (), "twice"),
        ((SourceSpec("a/b", 1),), (), "one key chunk"),
        ((SourceSpec("*", 1),), (), "one key chunk"),
        ((SourceSpec("a", 256),), (), "0-255"),
        ((SourceSpec("a", True),), (), "0-255"),  # type: ignore[arg-type]
        ((SourceSpec("a", 1, 0.0),), (), "positive"),
        ((SourceSpec("a", 1, math.nan),), (), "positive"),
        ((SourceSpec("a", 1),), (LockSpec("l", -1),), "0-255"),
        ((SourceSpec("a", 1),), (LockSpec("l", 1, -2.0),), "positive"),
    ],
)
def test_unusable_sources_and_locks_are_named(sources: tuple[SourceSpec, ...], locks: tuple[LockSpec, ...], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        Arbiter(sources, locks)


# --------------------------------------------------------------------------- against a plain model

_specs = st.lists(st.tuples(st.sampled_from([10, 50, 90, 100]), st.sampled_from([0.2, 0.5])), min_size=1, max_size=5)
_lock_specs = st.lists(st.tuples(st.sampled_from([10, 50, 90]), st.sampled_from([None, 0.3])), max_size=2)
_events = st.lists(
    st.tuples(
        st.sampled_from([0.0, 0.01, 0.1, 0.3]),
        st.sampled_from(["offer", "lock", "update", "update", "retune"]),
        st.integers(0, 4),
        st.booleans(),
    ),
    max_size=40,
)


class Model:
    """The arbitration rules written as plainly as they read: whom the arbiter must pick, from what it was told."""

    def __init__(self, sources: list[SourceSpec], locks: list[LockSpec]) -> None:
        self.sources, self.locks = sources, locks
        self.heard = {s.name: -math.inf for s in sources}
        self.lock_state = {lock.name: (False, -math.inf) for lock in locks}
        self.active: str | None = None

    def winner(self, now: float) -> str | None:
        engaged = [
            lock.priority
            for lock in self.locks
            if self.lock_state[lock.name][0] or (lock.timeout is not None and now >= self.lock_state[lock.name][1] + lock.timeout)
        ]
        blocked = max(engaged, default=-1)
        live = [s for s in self.sources if now < self.heard[s.name] + s.timeout and s.priority > blocked]
        if not live:
            return None
        top = max(s.priority for s in live)
        tied = [s for s in live if s.priority == top]
        if self.active in [s.name for s in tied]:
            return self.active
        return max(tied, key=lambda s: self.heard[s.name]).name  # the latest; the first configured among equals


@given(_specs, _lock_specs, _events)
# a retuned priority changes the winner with no source's timeout reached: the update must weigh again
@example(
    [(10, 0.5), (50, 0.5), (10, 0.5)],
    [],
    [(0.0, "offer", 0, False), (0.0, "offer", 1, False), (0.0, "update", 0, False), (0.0, "retune", 3, True), (0.0, "update", 0, False)],
)
def test_the_arbiter_picks_whom_the_plain_rules_pick(
    specs: list[tuple[int, float]], lock_specs: list[tuple[int, float | None]], events: list[tuple[float, str, int, bool]]
) -> None:
    sources = [SourceSpec(f"s{i}", priority, timeout) for i, (priority, timeout) in enumerate(specs)]
    locks = [LockSpec(f"l{i}", priority, timeout) for i, (priority, timeout) in enumerate(lock_specs)]
    arb, model = Arbiter(tuple(sources), tuple(locks)), Model(sources, locks)
    now = 0.0
    for step, kind, index, flag in events:
        now += step
        if kind == "offer":
            name = sources[index % len(sources)].name
            model.heard[name] = now
            model.active = model.winner(now)
            assert (arb.offer(name, twist(0.1), now) is Admission.DRIVES) == (model.active == name)
        elif kind == "lock" and locks:
            name = locks[index % len(locks)].name
            model.lock_state[name] = (flag, now)
            assert arb.set_lock(name, flag, now)
        elif kind == "retune":  # a parameter set live: weighed at the next update, as the gateway's core calls it
            i = index % len(sources)
            if flag:
                sources[i] = replace(sources[i], priority=[10, 50, 90, 100, 30][index])
                arb.retune(sources[i].name, priority=sources[i].priority)
            else:
                sources[i] = replace(sources[i], timeout=[0.2, 0.5, 0.05, 1.0, 0.3][index])
                arb.retune(sources[i].name, timeout=sources[i].timeout)
        else:
            before, model.active = model.active, model.winner(now)
            change = arb.update(now)
            assert (change is None) == (model.active == before)
        assert arb.active == model.active
