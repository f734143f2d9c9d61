"""TEMPORARY: the refactored governor against a copy of the one before (tests/governor_before.py), on random inputs."""

from __future__ import annotations

import copy
import math
from typing import Any

import governor_before as before
from hypothesis import HealthCheck, event, given, note, settings
from hypothesis import strategies as st
from test_safety import Host, inputs, safety_settings

from blackmetal.gateway.safety import Governor, SafetySettings


def plain(result: object) -> object:
    """Results of either governor, comparable (each has its own CommandReason)."""
    if isinstance(result, tuple):
        return tuple(plain(item) for item in result)
    if hasattr(result, "reason") and hasattr(result, "wheels"):
        return (result.wheels, result.reason.value)
    return result


def observe(gov: Any, t: float) -> tuple[object, ...]:
    return (gov.mode.value, gov.estop, gov.link_up, gov.accepted if gov.link_up else None, gov.last_cmd_at, gov.timed_out(t))


@settings(max_examples=3000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(safety_settings, st.lists(inputs, max_size=60))
def test_the_governor_does_what_it_did(safety: SafetySettings, ops: list[tuple[Any, ...]]) -> None:
    old = Host(before.Governor(before.SafetySettings(**{f: getattr(safety, f) for f in safety.__dataclass_fields__}), now=0.0))
    new = Host(Governor(safety))
    for op in [("link_up",), ("step", False), *ops]:
        if op[0] == "to_deadline":  # both go to the same time: the earlier deadline
            deadline = min(old.gov.next_deadline(op[2]), new.gov.next_deadline(op[2]))
            if math.isfinite(deadline):
                old.t = new.t = max(old.t, deadline + op[1])
            continue
        note(f"t={old.t!r} {op!r}")
        if op[0] in ("accepted", "dropped", "motion", "emg_dropped") and not old.gov.link_up:
            continue  # replies come only on a live link (the core clears its exchange on link down)
        a, b = plain(old.apply(op)), plain(new.apply(op))
        assert (old.t, old.last) == (new.t, new.last)
        assert a == b, f"{op}: {a} != {b}"
        assert observe(old.gov, old.t) == observe(new.gov, new.t)
        if op[0] in ("link_up", "estop"):  # the core steps after these at once
            assert plain(old.step(False)) == plain(new.step(False))
        if op[0] == "step":
            for congested in (False, True):
                d_old, d_new = old.gov.next_deadline(congested), new.gov.next_deadline(congested)
                note(f"  deadlines({congested}) old {d_old!r} new {d_new!r}")
                if d_old == d_new:
                    continue
                # where they differ, the earlier one must be a wake that does nothing, or one the old one got wrong
                first, host = (d_new, new) if d_new < d_old else (d_old, old)
                probe = copy.deepcopy(host)
                probe.t = max(first, probe.t)
                acted = plain(probe.step(congested)) != (False, None)
                note(f"  deadline({congested}) old {d_old!r} new {d_new!r}: {'new' if host is new else 'old'} acts at {first}: {acted}")
                event(
                    f"deadlines differ: {'new' if host is new else 'old'} earlier, acts {acted}, old behind {d_old <= old.t}, congested {congested}"
                )
                # an earlier new deadline may wake for nothing (harmless: test_safety checks it never spins);
                # a later one must not miss what the old one woke for
                assert host is new or d_old <= old.t or not acted, "the old deadline was earlier and something happened then"
