"""The safety governor's timing contract, property-tested: what the driver's CoreTimer relies on.

The driver's timer (``blackmetal.runtime.driver.CoreTimer``) runs the core's ``tick(now)``
at ``next_deadline()`` and after every input, and sleeps in between. Of the
governor it needs two things, for any sequence of inputs:

* after a step at ``now`` (EMG_STOP if due, then ``next_command(now, congested)``,
  as the core's ``_send_due`` does) the deadline lies after ``now``: one that
  does not would make the timer fire again at once, for ever;
* with no new input, a step at any time before that deadline sends nothing
  and changes nothing but the time of the look, so sleeping until the
  deadline misses nothing. The one exception is an acceleration ramp, which
  is continuous: its deadline is its next step at the latest, and a look
  before it takes the step earlier;

and of the ramp, whatever the looks: the twist never changes faster than the
acceleration limits allow for the time that passed (a ramp that starts after
a long standstill, or a brake after a long run at speed, steps from when it
started, not from the last look).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

from hypothesis import HealthCheck, example, given, note, settings
from hypothesis import strategies as st

from blackmetal.gateway.estop import read_estop
from blackmetal.gateway.safety import Driving, Governor, SafetySettings, State, VelocityCommand
from blackmetal.robot_model import WheelSpeeds
from blackmetal.schemas import ErrorReport, Twist, Vector3

ZERO = WheelSpeeds(left=0.0, right=0.0)


def twist(v: float = 0.0, w: float = 0.0) -> Twist:
    return Twist(linear=Vector3(x=v), angular=Vector3(z=w))


# 1e-9 is a command whose wheel speeds round to zero on the wire: a stop, though the twist is not zero
speeds = st.one_of(st.just(0.0), st.sampled_from([0.1, -0.2, 0.3, 1e-9]), st.floats(-1.5, 1.5, allow_nan=False))
twists = st.builds(twist, speeds, st.one_of(st.just(0.0), speeds))
any_dt = st.one_of(st.sampled_from([0.0, 1e-6, 0.001, 0.002, 0.005, 0.02]), st.floats(0.0, 0.6), st.floats(0.0, 12.0))

#: One input each, as the core hands them over; "step" is the core's _send_due, "to_deadline" sleeps until the deadline.
inputs = st.one_of(
    st.tuples(st.just("twist"), twists),
    st.tuples(st.just("handover"), twists, st.floats(0.0, 1.0)),  # an arbiter's hand-over: heard some time ago
    st.tuples(st.just("estop"), st.booleans()),
    st.tuples(st.just("link_up")),
    st.tuples(st.just("brake")),
    st.tuples(st.just("accepted"), st.sampled_from(["sent", "zero", "other"])),
    st.tuples(st.just("dropped"), st.sampled_from(["sent", "sent", "zero", "other"])),
    st.tuples(st.just("emg_dropped")),
    st.tuples(st.just("link_down")),
    st.tuples(st.just("motion"), st.sampled_from([0.0, 0.005, 0.4])),
    st.tuples(st.just("wait"), any_dt),
    st.tuples(st.just("to_deadline"), st.sampled_from([-1e-4, 0.0, 0.0, 1e-4]), st.booleans()),
    st.tuples(st.just("step"), st.booleans()),
    st.tuples(st.just("step"), st.booleans()),
)

safety_settings = st.builds(
    SafetySettings,
    cmd_timeout=st.sampled_from([0.0, 0.5, 0.05]),
    keepalive=st.sampled_from([5.0, 0.3]),
    linear_accel=st.sampled_from([None, None, 0.5]),
    angular_accel=st.sampled_from([None, None, 2.0]),
    full_buffer_retries=st.sampled_from([0, 2, 5]),
    max_command_hz=st.sampled_from([500.0, 100.0, 20.0]),
)


@dataclass
class Host:
    """Drives a governor the way the gateway's core does; ``t`` is the fake monotonic clock."""

    gov: Any
    t: float = 0.0
    #: The wheels of the last velocity command sent (what a reply answers).
    last: WheelSpeeds | None = None

    def apply(self, op: tuple[Any, ...]) -> object:
        gov, now, kind = self.gov, self.t, op[0]
        if kind == "twist":
            return gov.on_twist(op[1], now)
        if kind == "handover":
            return gov.on_twist(op[1], now - op[2], now)
        if kind == "estop":
            return gov.on_estop(op[1], now)
        if kind == "link_up":
            return gov.on_link_up(now)
        if kind == "link_down":
            return gov.on_link_down()
        if kind == "brake":
            return gov.brake(now)
        if kind in ("accepted", "dropped"):
            wheels = {"sent": self.last or ZERO, "zero": ZERO, "other": WheelSpeeds(left=0.123, right=-0.1)}[op[1]]
            return gov.on_accepted(wheels, now) if kind == "accepted" else gov.on_dropped(wheels, now)
        if kind == "emg_dropped":
            return gov.on_emg_stop_dropped(now)
        if kind == "motion":
            return gov.observe_motion(op[1], -op[1], now)
        if kind == "wait":
            self.t += op[1]
            return None
        if kind == "to_deadline":
            deadline = gov.next_deadline(op[2])
            if math.isfinite(deadline):
                self.t = max(self.t, deadline + op[1])
            return None
        assert kind == "step", kind
        return self.step(op[1])

    def step(self, congested: bool) -> tuple[bool, VelocityCommand | None]:
        """What the core's _send_due does: EMG_STOP first if due, then the velocity command."""
        emg = self.gov.emg_stop_due(self.t)
        if emg:
            self.gov.on_emg_stop_sent()
        command = self.gov.next_command(self.t, congested)
        if command is not None:
            self.last = command.wheels
        return emg, command


def ramping(state: State) -> bool:
    return isinstance(state, Driving) and state.current != state.target


LINK_UP = [("link_up",), ("step", False)]


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(safety_settings, st.lists(inputs, max_size=60), st.lists(st.floats(0.0, 0.999), min_size=62, max_size=62))
# what the governor before the state refactor got wrong:
# a new motion waits on a congested robot while its wheels turn after an accepted stop (the stop-again time stayed due): spun
@example(
    SafetySettings(cmd_timeout=0.0),
    [("accepted", "zero"), ("motion", 0.4), ("wait", 1.0), ("twist", twist(0.2)), ("step", True)],
    [0.0] * 62,
)
# a re-send of a stop stayed due while a new motion waited for the rate cap: spun
@example(
    SafetySettings(cmd_timeout=0.0, max_command_hz=100.0),
    [("dropped", "sent"), ("to_deadline", 0.0, False), ("twist", twist(0.0, 0.1)), ("step", False)],
    [0.0] * 62,
)
# a stop whose twist is not zero (its wheels round to zero) had its re-send left out of the congested deadline: missed
@example(
    SafetySettings(cmd_timeout=0.0, full_buffer_retries=0),
    [("twist", twist(0.0, 1e-136)), ("dropped", "sent"), ("step", True)],
    [0.5] * 62,
)
def test_nothing_is_due_before_the_deadline_and_the_deadline_is_never_behind(
    safety: SafetySettings, ops: list[tuple[Any, ...]], probes: list[float]
) -> None:
    host = Host(Governor(safety))
    for i, op in enumerate([*LINK_UP, *ops]):
        note(f"t={host.t!r} {op!r}")
        host.apply(op)
        if op[0] != "step":
            continue
        congested, now = op[1], host.t
        deadline = host.gov.next_deadline(congested)
        note(f"  -> deadline {deadline!r}, state {host.gov.state!r}")
        assert deadline > now, "after a step at now the deadline must lie after now, or the host's timer fires again at once"
        if ramping(host.gov.state):
            continue  # a ramp is continuous: a look before its next step takes the step earlier
        probe = copy.deepcopy(host)
        probe.t = now + probes[i] * (min(deadline, now + 30.0) - now)
        assert probe.step(congested) == (False, None), f"something was due at {probe.t!r}, before the deadline {deadline!r}"
        assert probe.gov.state == host.gov.state, "a look before the deadline changed the state"
        assert probe.gov.next_deadline(congested) == deadline


ramp_settings = st.builds(
    SafetySettings,
    cmd_timeout=st.sampled_from([0.0, 0.5, 0.05]),
    linear_accel=st.sampled_from([0.5, 3.0]),
    angular_accel=st.sampled_from([2.0, 0.1]),
    max_command_hz=st.sampled_from([500.0, 20.0]),
)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ramp_settings, st.lists(inputs, max_size=60))
# before the ramp's clock stood still while settled: a look long after the last one stepped a new ramp all at once
@example(SafetySettings(cmd_timeout=0.0, linear_accel=0.5, angular_accel=2.0), [("wait", 5.0), ("twist", twist(1.0)), ("step", False)])
# a brake long after the last look ramped down as if the brake had struck at that look
@example(
    SafetySettings(cmd_timeout=0.5, linear_accel=3.0, angular_accel=2.0),
    [("twist", twist(0.3)), ("step", False), ("wait", 0.6), ("step", False)],
)
def test_the_twist_never_changes_faster_than_the_acceleration_limits(safety: SafetySettings, ops: list[tuple[Any, ...]]) -> None:
    host = Host(Governor(safety))
    assert safety.linear_accel is not None and safety.angular_accel is not None
    seen: tuple[float, tuple[float, float]] | None = None  # (t, the twist then) while driving on one link
    for op in [*LINK_UP, *ops]:
        host.apply(op)
        state = host.gov.plan(host.t)[0]  # the twist as of now, whether or not anything looked
        if not isinstance(state, Driving) or op[0] == "link_up":
            seen = None  # no link, an e-stop, or a new link (which starts from standstill): a new ramp starts
            continue
        if seen is not None:
            dt = host.t - seen[0]
            note(f"t={host.t!r} {op!r}: {seen[1]!r} -> {state.current!r} in {dt!r} s")
            assert abs(state.current[0] - seen[1][0]) <= safety.linear_accel * dt + 1e-9
            assert abs(state.current[1] - seen[1][1]) <= safety.angular_accel * dt + 1e-9
        seen = (host.t, state.current)


# ----------------------------------------------------------------------------- the core's hand-over


def handed_over_after(refuse: str) -> tuple[Any, float]:
    """teleop holds the robot at 0; nav's 0.3 waits behind it; then ``refuse`` happens and teleop falls silent (0.5 s)."""
    from blackmetal.schemas import GatewayHealth, encode
    from unit.gateway.test_core import Bench, twist_payload

    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.conn.on_cmd_vel("teleop", twist_payload(0.0), bench.t)
    bench.run(0.3)
    bench.conn.on_cmd_vel("nav", twist_payload(0.3), bench.t)  # dropped quietly: teleop drives
    if refuse == "estop":
        bench.conn.on_estop(read_estop(b'{"engaged": true}'), bench.t)
    else:
        mine = bench.conn.health(bench.t)
        other = GatewayHealth(stamp=mine.stamp, control=mine.control, log=mine.log, source="another-run")
        bench.conn.on_health_seen(encode(other), bench.t)
    bench.settle()
    since = bench.t
    bench.run(0.3)  # teleop falls silent (at 0.5 s), nav (heard at 0.3 s) is live: its command is handed over
    assert bench.conn.arbiter.active == "nav"
    return bench, since


def test_a_command_handed_over_during_an_estop_is_refused_and_reported() -> None:
    bench, since = handed_over_after("estop")
    assert all(left == 0.0 for t, left, _ in bench.velocity() if t >= since)
    (report,) = [e for e in bench.of(ErrorReport) if e.key == "robot/cmd_vel/nav"]
    assert "handed over to it, is refused: emergency stop is engaged" in report.reason and '"x":0.3' in report.excerpt
    assert bench.conn.counters.rejected_inputs == 1


def test_a_command_handed_over_while_a_second_gateway_drives_is_refused() -> None:
    bench, since = handed_over_after("conflict")
    assert all(left == 0.0 for t, left, _ in bench.velocity() if t >= since)  # before: nav's 0.3 went out
    assert any(e.key == "robot/cmd_vel/nav" and "another gateway (run another-run)" in e.reason for e in bench.of(ErrorReport))
