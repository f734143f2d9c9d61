"""Odometry core: conversion, exact arcs, the sample rules and accuracy.

The glitch rules are test_glitches.py's; streaming == batch is test_batch.py's.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import exact_pose

from blackmetal import robot_model as facts
from blackmetal.bench.synth import Leg, SynthLog, square_legs, synth_log
from blackmetal.odometry_service.batch import run_batch
from blackmetal.odometry_service.errors import SampleRejected
from blackmetal.odometry_service.integrator import Odometry
from blackmetal.odometry_service.params import OdometryParams
from blackmetal.odometry_service.sample_order import EpochStart, EpochTally, SampleOrder, Verdict
from blackmetal.robot_model import NOMINAL_ENCODERS, Encoders, arc_step, wheels_to_twist
from blackmetal.schemas import WheelImpulses

IPM_L, IPM_R = facts.IMPULSES_PER_METER_LEFT, facts.IMPULSES_PER_METER_RIGHT


def imp(seq: int, stamp: float, left: float, right: float) -> WheelImpulses:
    """A sample with rim speeds in m/s turned into the robot's impulses (right mirrored)."""
    return WheelImpulses(seq=seq, stamp=stamp, left=round(left * IPM_L), right=-round(right * IPM_R))


def test_conversion_mirrors_the_right_wheel() -> None:
    params = OdometryParams()
    left, right = params.encoders.to_speeds(1013, -1054)
    assert left == pytest.approx(1.0, abs=1e-3) and right == pytest.approx(1.0, abs=1e-3)
    assert OdometryParams(encoders=Encoders(mirror_right=False)).encoders.to_speeds(0, 1054)[1] > 0


def test_straight_line_uses_real_time_steps() -> None:
    odo = Odometry(OdometryParams(filter_alpha=0.0))
    t = 100.0
    for k in range(200):
        odo.feed(WheelImpulses(seq=k, stamp=t, left=203, right=-211))
        t += 0.005 if k % 2 else 0.015  # jittered polls: the real time between samples counts
    v_left, v_right = 203 / IPM_L, 211 / IPM_R
    expected = 0.5 * (v_left + v_right) * (t - 100.0 - (0.015 if 199 % 2 == 0 else 0.005))
    assert odo.x == pytest.approx(expected, rel=1e-6)  # the wheels differ by 0.2 mm/s: a very slight arc


@pytest.mark.parametrize("v, w", [(0.2, 0.5), (0.1, -1.2), (0.0, 1.0), (0.3, 0.0)])
def test_exact_arc_matches_the_closed_form_circle(v: float, w: float) -> None:
    sep = 0.5
    x = y = yaw = 0.0
    total = 0.0
    for dt in [0.01, 0.013, 0.007, 0.02] * 50:
        x, y, yaw = arc_step(x, y, yaw, (v - w * sep / 2) * dt, (v + w * sep / 2) * dt, sep)
        total += dt
    if w == 0:
        assert (x, y, yaw) == pytest.approx((v * total, 0.0, 0.0), abs=1e-12)
    else:
        r = v / w
        assert x == pytest.approx(r * math.sin(w * total), abs=1e-12)
        assert y == pytest.approx(r * (1 - math.cos(w * total)), abs=1e-12)
        assert yaw == pytest.approx(w * total, abs=1e-12)


def test_yaw_is_wrapped_in_the_published_pose() -> None:
    odo = Odometry(OdometryParams(filter_alpha=0.0))
    t = 0.0
    pose = None
    for k in range(1000):  # 10 s turning in place at 1 rad/s: several wraps
        pose = odo.feed(imp(k, t, -0.25, 0.25))
        t += 0.01
    assert pose is not None
    assert -math.pi <= pose.yaw <= math.pi
    assert odo.yaw == pytest.approx(9.99, abs=0.03)  # whole impulses: 0.1% slow
    assert pose.yaw == pytest.approx(math.remainder(odo.yaw, math.tau), abs=1e-12)
    assert pose.orientation.z == pytest.approx(math.sin(pose.yaw / 2))
    assert pose.w == pytest.approx(1.0, abs=0.01) and pose.v == pytest.approx(0.0, abs=1e-3)


def test_the_low_pass_does_not_bias_the_distance() -> None:
    """A run that starts fast and ends slow: integrating filtered speeds would over-count."""
    smooth, raw = Odometry(OdometryParams(filter_alpha=0.9)), Odometry(OdometryParams(filter_alpha=0.0))
    speeds = [0.3] * 20 + [0.05] * 20 + [0.0, 0.0]
    for k, v in enumerate(speeds):
        sample = imp(k, 0.02 * k, v, v)
        smooth.feed(sample)
        raw.feed(sample)
    assert smooth.x == pytest.approx(raw.x, abs=1e-12)
    assert smooth.x == pytest.approx(0.3 * 19 * 0.02 + 0.05 * 20 * 0.02, abs=2e-3)


def test_dropout_in_motion_costs_nothing() -> None:
    clean, faulty = Odometry(), Odometry()
    for k in range(100):
        sample = imp(k, 0.01 * k, 0.2, 0.2)
        clean.feed(sample)
        faulty.feed(WheelImpulses(seq=k, stamp=sample.stamp, left=0, right=sample.right) if k == 50 else sample)
    assert faulty.x == pytest.approx(clean.x, abs=1e-12)
    assert faulty.glitches.dropouts == 1


def test_a_real_stop_is_exact_not_one_sample_too_long() -> None:
    odo = Odometry()
    for k in range(100):
        odo.feed(imp(k, 0.01 * k, 0.2, 0.2))
    at_last_motion = odo.x
    provisional = odo.feed(imp(100, 1.0, 0.0, 0.0))  # first zero: held, as the original did
    assert provisional.x > at_last_motion
    final = odo.feed(imp(101, 1.01, 0.0, 0.0))  # second zero: it was a stop, the held step is taken back
    assert final.x == pytest.approx(at_last_motion, abs=1e-12)
    assert odo.retractions == 1 and odo.glitches.dropouts == 0 and final.v == 0.0


def test_spikes_are_rejected() -> None:
    clean, faulty = Odometry(), Odometry()
    for k in range(100):
        sample = imp(k, 0.01 * k, 0.2, 0.2)
        clean.feed(sample)
        faulty.feed(WheelImpulses(seq=k, stamp=sample.stamp, left=5000, right=-9000) if k % 25 == 3 else sample)
    assert faulty.x == pytest.approx(clean.x, abs=1e-12)
    assert faulty.glitches.spikes == 8


def test_out_of_order_duplicate_and_backwards_samples_are_rejected() -> None:
    odo = Odometry()
    odo.feed(imp(5, 10.0, 0.1, 0.1))
    odo.feed(imp(6, 10.01, 0.1, 0.1))
    with pytest.raises(SampleRejected, match="duplicate or out-of-order"):
        odo.feed(imp(6, 10.01, 0.1, 0.1))
    with pytest.raises(SampleRejected, match="duplicate or out-of-order"):
        odo.feed(imp(4, 9.0, 0.1, 0.1))
    with pytest.raises(SampleRejected, match="stamp went backwards"):
        odo.feed(imp(7, 10.0, 0.1, 0.1))
    odo.feed(imp(9, 10.03, 0.1, 0.1))  # two missed polls: integrated honestly
    assert odo.tally.missed == 2


def test_a_restarted_gateway_is_a_new_epoch_not_a_fault() -> None:
    odo = Odometry()
    for k in range(50):
        odo.feed(imp(1000 + k, 0.01 * k, 0.2, 0.2))
    x = odo.x
    odo.feed(imp(0, 3.0, 0.2, 0.2))  # sequence starts over, stamp moves on
    assert odo.x == x and odo.tally.restarts == 1 and odo.events
    odo.feed(imp(1, 3.01, 0.2, 0.2))
    assert odo.x > x


def test_a_long_gap_is_reported_not_guessed() -> None:
    odo = Odometry(OdometryParams(max_gap=0.5))
    odo.feed(imp(0, 0.0, 0.2, 0.2))
    odo.feed(imp(1, 0.01, 0.2, 0.2))
    x = odo.x
    odo.feed(imp(2, 2.0, 0.2, 0.2))
    assert odo.x == x and odo.tally.gaps == 1 and "gap" in odo.events[-1]
    odo.feed(imp(3, 2.2, 0.2, 0.2))  # 0.2 s: within the bound, integrated
    assert odo.x == pytest.approx(x + 0.04, abs=1e-3)


def test_sample_order_names_why_an_epoch_starts() -> None:
    order = SampleOrder(max_gap=0.5, live=False)
    kinds = [
        order.check(0, 1.0, None, None, None).start,
        order.check(1, 1.01, None, None, None).start,
        order.check(2, 2.0, None, None, None).start,  # 0.99 s later
        order.check(0, 2.01, None, None, None).start,  # no sources: the sequence started over
    ]
    assert kinds == [EpochStart.FIRST, None, EpochStart.GAP, EpochStart.SEQUENCE_RESTART]
    order = SampleOrder(max_gap=0.5, live=False)
    order.check(7, 1.0, 1.0, "gw-a", None)
    assert order.check(0, 1.01, 0.01, "gw-b", None).start is EpochStart.GATEWAY_RESTART  # gw-a silent (no arrivals: a log)


def test_gaps_and_restarts_are_counted_by_kind_never_by_text() -> None:
    tally = EpochTally()
    tally.count(Verdict(EpochStart.GAP, 0.0, missed=2, event="gateway restart, it seems"))
    tally.count(Verdict(EpochStart.GATEWAY_RESTART, 0.0, event="a gap, a gap"))
    tally.count(Verdict(EpochStart.SEQUENCE_RESTART, 0.0, event=None))
    tally.count(Verdict(EpochStart.FIRST, 0.0, event="gap"))
    assert (tally.gaps, tally.restarts, tally.missed) == (1, 2, 2)
    # gateways whose ids contain "gap": the take-over is a restart, live and in a replay
    samples = [WheelImpulses(seq=100 + k, stamp=0.02 * k, left=203, right=-211, mono=0.02 * k, source="gap-a") for k in range(10)]
    samples += [WheelImpulses(seq=k, stamp=5.0 + 0.02 * k, left=203, right=-211, mono=0.02 * k, source="gap-b") for k in range(10)]
    odo = Odometry()
    for sample in samples:
        odo.feed(sample)
    batch = run_batch(
        np.array([m.seq for m in samples]),
        np.array([m.stamp for m in samples]),
        np.array([m.left for m in samples]),
        np.array([m.right for m in samples]),
        mono=np.array([m.mono for m in samples]),
        sources=[m.source for m in samples],
    )
    assert (odo.tally.restarts, odo.tally.gaps, odo.tally.missed) == (batch.restarts, batch.gaps, batch.missed) == (1, 0, 0)
    assert "gap-b" in odo.events[-1] and batch.events == odo.events


def test_reset_to_a_given_pose() -> None:
    odo = Odometry()
    odo.feed(imp(0, 0.0, 0.2, 0.2))
    odo.feed(imp(1, 0.01, 0.2, 0.2))
    pose = odo.reset(1.0, 2.0, 3.0)
    assert (pose.x, pose.y, pose.yaw) == (1.0, 2.0, 3.0)
    odo.feed(imp(2, 0.02, 0.2, 0.2))  # a reset clears every state: this sample starts a new epoch
    assert (odo.x, odo.y) == (1.0, 2.0)
    odo.feed(imp(3, 0.03, 0.2, 0.2))
    assert odo.x < 1.0  # heading 3 rad points backwards


# ----------------------------------------------------------------------------- accuracy


@pytest.mark.parametrize("clockwise", [False, True])
def test_faulty_square_replay_closes_on_the_exact_answer(clockwise: bool) -> None:
    legs = square_legs(side=2.0, clockwise=clockwise)
    exact = exact_pose(legs)
    assert exact[0] == pytest.approx(0.0, abs=1e-9) and exact[1] == pytest.approx(0.0, abs=1e-9)
    log = synth_log(legs, dt_range=(0.005, 0.015), dropout=0.01, spike=0.005, seed=11)
    result = run_batch(log.seq, log.stamp, log.left, log.right)
    err_pos = math.hypot(result.x[-1] - exact[0], result.y[-1] - exact[1])
    err_yaw = abs(math.remainder(result.yaw[-1] - exact[2], math.tau))
    assert err_pos < 0.010, err_pos
    assert err_yaw < 0.010, err_yaw
    assert result.spikes > 0 and result.dropouts > 0 and result.retractions > 0
    # the original driver (assumed period, held stops) misses by far more on the same log
    ox, oy, _oyaw = original_algorithm(log, period=0.010)
    assert math.hypot(ox - exact[0], oy - exact[1]) > 2 * err_pos


def test_stop_and_go_legs_are_exact() -> None:
    legs = [Leg(0.3, 0, 0), Leg(1.0, 0.2, 0.2), Leg(0.3, 0, 0), Leg(1.0, 0.1, 0.3), Leg(0.3, 0, 0)]
    log = synth_log(legs, dropout=0.0, spike=0.0, seed=2)
    result = run_batch(log.seq, log.stamp, log.left, log.right)
    exact = exact_pose(legs)
    assert math.hypot(result.x[-1] - exact[0], result.y[-1] - exact[1]) < 2e-3
    assert abs(result.yaw[-1] - exact[2]) < 5e-3


def original_algorithm(
    log: SynthLog,
    period: float,
    alpha: float = 0.3,
    encoders: Encoders = NOMINAL_ENCODERS,
    separation: float = facts.WHEEL_SEPARATION,
    max_wheel_speed: float = facts.MAX_WHEEL_SPEED,
) -> tuple[float, float, float]:
    """The original driver's odometry, for comparison: its filter rules, Euler steps of an assumed period."""
    x = y = yaw = 0.0
    outputs = [0.0, 0.0]
    zeros = [2, 2]
    for left, right in zip(log.left.tolist(), log.right.tolist(), strict=False):
        speeds = encoders.to_speeds(float(left), float(right))
        for i, value in enumerate(speeds):
            if abs(value) > max_wheel_speed:
                value = outputs[i]  # the original dropped impossible spikes
            if value == 0.0:
                zeros[i] += 1
                if zeros[i] >= 2:
                    outputs[i] = 0.0
            else:
                outputs[i] = value if zeros[i] >= 2 else alpha * outputs[i] + (1 - alpha) * value
                zeros[i] = 0
        v, w = wheels_to_twist(outputs[0], outputs[1], separation)
        x += v * math.cos(yaw) * period
        y += v * math.sin(yaw) * period
        yaw += w * period
    return x, y, yaw
