"""Odometry input with integrity: stamps cannot freeze it, plausible lies cannot steer it, a reset recovers it."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from odometry_service.batch import run_batch
from odometry_service.errors import OdometryError, SampleRejected
from odometry_service.integrator import Odometry
from schemas import WheelImpulses

WALL = 1_800_000_000.0
FWD = (203, -211)  # about 0.2 m/s on both wheels


def sample(seq: int, mono: float, stamp: float | None = None, source: str | None = "gw-a", wheels: tuple[int, int] = FWD) -> WheelImpulses:
    return WheelImpulses(seq=seq, stamp=WALL + mono if stamp is None else stamp, left=wheels[0], right=wheels[1], mono=mono, source=source)


def drive(odo: Odometry, seconds: float, start_seq: int = 0, start: float = 0.0, **kwargs: object) -> list[float]:
    """Feed 50 Hz samples, arriving on time; the x after each."""
    xs = []
    for k in range(int(seconds * 50)):
        t = start + k * 0.02
        odo.feed(sample(start_seq + k, t, **kwargs), arrival=t)  # type: ignore[arg-type]
        xs.append(odo.x)
    return xs


def test_a_stamp_a_day_ahead_neither_freezes_nor_stretches_the_pose() -> None:
    odo = Odometry()
    drive(odo, 1.0)
    x_before = odo.x
    odo.feed(sample(50, 1.0, stamp=WALL + 86_400.0), arrival=1.0)  # one stamp from tomorrow
    xs = drive(odo, 1.0, start_seq=51, start=1.02)
    assert all(b > a for a, b in itertools.pairwise(xs))  # every later sample moves it: not frozen
    assert xs[-1] - x_before == pytest.approx(0.2 * 1.02, rel=0.02)  # and no day of travel either


def test_a_wall_clock_step_back_of_3_s_does_not_freeze_the_pose() -> None:
    odo = Odometry()
    drive(odo, 1.0)
    frozen = 0
    for k in range(50):  # the gateway's wall clock jumped back 3 s (NTP); its monotonic time did not
        t = 1.0 + k * 0.02
        before = odo.x
        odo.feed(sample(50 + k, t, stamp=WALL + t - 3.0), arrival=t)
        frozen += odo.x == before
    assert frozen == 0  # frozen for 0 s (was 3.3 s and 1.2 m lost)


def test_samples_claiming_more_time_than_they_took_are_rejected() -> None:
    """200 samples sent at 1 kHz, each claiming 0.49 s at 0.84 m/s: the pose does not move (was 81.7 m)."""
    odo = Odometry()
    drive(odo, 0.5)
    x0, rejected = odo.x, 0
    for k in range(200):
        arrival = 0.5 + k * 0.001
        try:
            odo.feed(sample(25 + k, 0.5 + 0.49 * (k + 1), wheels=(850, -885)), arrival=arrival)
        except SampleRejected as exc:
            rejected += 1
            assert "claims" in str(exc)
    assert rejected == 200 and odo.x == x0


def test_old_sequence_numbers_with_fresh_stamps_are_rejected() -> None:
    odo = Odometry()
    drive(odo, 1.0)
    yaw0 = odo.yaw
    for k in range(20):  # replayed seq 0..19 with new stamps, from the same gateway
        with pytest.raises(SampleRejected, match="out-of-order"):
            odo.feed(sample(k, 1.0 + 0.02 * k, wheels=(-203, -211)), arrival=1.0 + 0.02 * k)
    assert odo.yaw == yaw0  # was 1.19 rad of fake yaw


def test_a_second_gateway_on_the_key_is_rejected_until_the_first_is_gone() -> None:
    odo = Odometry()
    drive(odo, 1.0)
    with pytest.raises(SampleRejected, match="two gateways"):
        odo.feed(sample(0, 5.0, source="gw-b"), arrival=1.0)
    drive(odo, 0.2, start_seq=50, start=1.0)
    x = odo.x
    odo.feed(sample(0, 9.0, source="gw-b"), arrival=3.0)  # gw-a silent for 1.8 s: a restarted gateway takes over
    assert odo.restarts == 1 and odo.x == x  # a new epoch: nothing integrated across the switch
    odo.feed(sample(1, 9.02, source="gw-b"), arrival=3.02)
    assert odo.x > x


def test_reset_clears_a_poisoned_state_and_refuses_absurd_poses() -> None:
    odo = Odometry()
    old = [WheelImpulses(seq=k, stamp=WALL + 0.02 * k, left=203, right=-211) for k in range(10)]  # a gateway without mono
    for s in old:
        odo.feed(s)
    odo.feed(WheelImpulses(seq=10, stamp=WALL + 86_400.0, left=203, right=-211))  # poisoned: a day ahead
    with pytest.raises(SampleRejected):
        odo.feed(WheelImpulses(seq=11, stamp=WALL + 0.22, left=203, right=-211))
    for bad in ({"x": 1e308}, {"yaw": 1e308}, {"x": math.nan}, {"y": -2e6}):
        with pytest.raises(OdometryError, match=next(iter(bad))):
            odo.reset(**bad)  # type: ignore[arg-type]
    odo.reset()
    odo.feed(WheelImpulses(seq=12, stamp=WALL + 0.24, left=203, right=-211))
    odo.feed(WheelImpulses(seq=13, stamp=WALL + 0.26, left=203, right=-211))
    assert odo.x == pytest.approx(0.2 * 0.02, rel=0.02)  # following again
    assert abs(odo.pose().yaw) < 1e-4


def test_replay_of_a_log_with_mono_and_sources_equals_the_live_pipeline() -> None:
    samples = [sample(k, 0.02 * k, stamp=WALL + 0.02 * k - (3.0 if k > 40 else 0.0)) for k in range(80)]  # a clock step
    samples += [sample(k, 10.0 + 0.02 * k, source="gw-b") for k in range(40)]  # a restart
    samples.insert(30, sample(5, 0.61))  # an old sequence number: rejected by both
    live = Odometry()
    poses = []
    for s in samples:
        try:
            poses.append(live.feed(s))
        except SampleRejected:
            pass
    batch = run_batch(
        np.array([s.seq for s in samples]),
        np.array([s.stamp for s in samples]),
        np.array([s.left for s in samples]),
        np.array([s.right for s in samples]),
        mono=np.array([s.mono for s in samples]),
        sources=[s.source for s in samples],
    )
    assert len(batch) == len(poses) == 120
    assert np.allclose(batch.x, [p.x for p in poses], atol=1e-9) and np.allclose(batch.y, [p.y for p in poses], atol=1e-9)
    assert batch.restarts == live.restarts == 1 and len(batch.rejected) == 1


def test_delivery_jitter_on_a_loaded_machine_is_never_mistaken_for_a_lie() -> None:
    rng = np.random.default_rng(4)
    odo = Odometry()
    arrival = mono = 0.0
    for k in range(2000):  # 40 s at 50 Hz, each delivered 0-300 ms late, in order, polls sometimes 150 ms apart
        mono += 0.15 if k % 97 == 96 else 0.02
        arrival = max(arrival, mono + float(rng.uniform(0.0, 0.3)))
        odo.feed(sample(k, mono), arrival=arrival)  # raises if rejected
    assert odo.samples == 2000
