"""The odometry in numpy for replays (:mod:`blackmetal.odometry_service.batch`): the streaming path's poses, to 1e-9.

Replay, calibration and the bench read a whole log at once; what they
compute must be what the live service would have published, sample by
sample, on the same log (its faults, rejections, restarts and gaps included).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from blackmetal.bench.synth import square_legs, synth_log
from blackmetal.odometry_service.batch import integrate, linear_scan, run_batch
from blackmetal.odometry_service.errors import SampleRejected
from blackmetal.odometry_service.integrator import Odometry
from blackmetal.odometry_service.params import OdometryParams
from blackmetal.robot_model import PARALLEL_MIN
from blackmetal.schemas import WheelImpulses


def stream(messages: list[WheelImpulses], params: OdometryParams) -> tuple[list[tuple[float, ...]], Odometry]:
    odo = Odometry(params)
    poses = []
    for msg in messages:
        try:
            odo.feed(msg)
        except SampleRejected:
            continue
        poses.append((odo.stamp, odo.x, odo.y, odo.yaw, odo.v, odo.w))
    return poses, odo


@pytest.mark.parametrize("alpha", [0.0, 0.3, 0.9])
def test_batch_equals_streaming_on_a_faulty_square(alpha: float) -> None:
    params = OdometryParams(filter_alpha=alpha)
    log = synth_log(square_legs(), dropout=0.05, spike=0.02, seed=3)
    poses, odo = stream(log.messages(), params)
    batch = run_batch(log.seq, log.stamp, log.left, log.right, params)
    expected = np.array(poses)
    got = np.column_stack([batch.stamp, batch.x, batch.y, batch.yaw, batch.v, batch.w])
    assert got.shape == expected.shape
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    assert (batch.spikes, batch.dropouts, batch.retractions) == (odo.glitches.spikes, odo.glitches.dropouts, odo.retractions)


def test_batch_equals_streaming_on_a_log_long_enough_for_two_threads() -> None:
    """From PARALLEL_MIN samples the wheels and the trigonometry run on two threads: same poses."""
    params = OdometryParams()
    legs = square_legs(side=0.5) * 60
    log = synth_log(legs, dropout=0.02, spike=0.01, seed=5)
    assert len(log) >= PARALLEL_MIN
    poses, odo = stream(log.messages(), params)
    batch = run_batch(log.seq, log.stamp, log.left, log.right, params)
    got = np.column_stack([batch.stamp, batch.x, batch.y, batch.yaw, batch.v, batch.w])
    np.testing.assert_allclose(got, np.array(poses), rtol=0, atol=1e-9)
    assert (batch.spikes, batch.dropouts, batch.retractions) == (odo.glitches.spikes, odo.glitches.dropouts, odo.retractions)


def test_batch_equals_streaming_on_an_irregular_log() -> None:
    params = OdometryParams()
    log = synth_log(square_legs(side=0.5), dropout=0.05, spike=0.02, seed=4)
    msgs = log.messages()
    msgs.insert(100, msgs[99])  # duplicate
    msgs.insert(200, msgs[150])  # out of order
    msgs[300] = WheelImpulses(seq=msgs[300].seq, stamp=msgs[299].stamp - 1.0, left=0, right=0)  # backwards
    restart = [WheelImpulses(seq=i, stamp=m.stamp + 1.0, left=m.left, right=m.right) for i, m in enumerate(msgs[400:])]
    msgs = msgs[:400] + restart  # gateway restarted, with a 1 s gap too
    poses, odo = stream(msgs, params)
    arr = np.array([(m.seq, m.stamp, m.left, m.right) for m in msgs])
    batch = run_batch(arr[:, 0].astype(np.int64), arr[:, 1], arr[:, 2], arr[:, 3], params)
    np.testing.assert_allclose(np.column_stack([batch.x, batch.y, batch.yaw]), np.array(poses)[:, 1:4], atol=1e-9)
    assert len(batch.rejected) == 3 and batch.restarts == odo.tally.restarts == 1


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(st.sampled_from([0, 0, 0, 150, -150, 203, 400, 5000]), st.sampled_from([0, 0, -211, 211, -400, -9000])),
        min_size=1,
        max_size=120,
    ),
    st.lists(st.floats(0.0, 0.02), min_size=120, max_size=120),
    st.floats(0.0, 0.95),
)
def test_batch_equals_streaming_on_random_logs(readings: list[tuple[int, int]], dts: list[float], alpha: float) -> None:
    params = OdometryParams(filter_alpha=alpha, max_gap=0.015)
    stamps = 1000.0 + np.cumsum(dts[: len(readings)])
    msgs = [WheelImpulses(seq=k, stamp=float(t), left=lw, right=r) for k, (t, (lw, r)) in enumerate(zip(stamps, readings, strict=False))]
    poses, _ = stream(msgs, params)
    batch = run_batch(np.arange(len(msgs)), stamps, np.array([m.left for m in msgs]), np.array([m.right for m in msgs]), params)
    np.testing.assert_allclose(np.column_stack([batch.x, batch.y, batch.yaw, batch.v, batch.w]), np.array(poses)[:, 1:], atol=1e-9)


def test_linear_scan_matches_the_recursion() -> None:
    rng = np.random.default_rng(0)
    a = rng.choice([0.0, 0.3, 1.0], 5000, p=[0.05, 0.9, 0.05])
    b = rng.normal(size=5000)
    y, prev = np.empty(5000), 0.0
    for k in range(5000):
        prev = a[k] * prev + b[k]
        y[k] = prev
    np.testing.assert_allclose(linear_scan(a, b), y, atol=1e-12)


def test_an_empty_log_has_no_pose() -> None:
    result = run_batch(np.array([], np.int64), np.array([]), np.array([]), np.array([]))
    assert len(result) == 0 and result.rejected == [] and (result.spikes, result.dropouts) == (0, 0)


def test_intervals_are_measured_on_mono_so_a_wall_clock_step_bends_nothing() -> None:
    n = 50
    seq, mono = np.arange(n), 100.0 + 0.02 * np.arange(n)
    wall = 1_700_000_000.0 + 0.02 * np.arange(n)
    stepped = wall - np.where(np.arange(n) >= 25, 0.5, 0.0)  # NTP set the clock back 0.5 s mid-run, within the gap limit
    left, right = np.full(n, 203), np.full(n, -211)
    steady = run_batch(seq, wall, left, right, mono=mono, sources=["gw"] * n)
    bent = run_batch(seq, stepped, left, right, mono=mono, sources=["gw"] * n)
    np.testing.assert_array_equal(np.column_stack([bent.x, bent.y, bent.yaw]), np.column_stack([steady.x, steady.y, steady.yaw]))
    assert bent.rejected == [] and list(bent.stamp) == list(stepped)  # each pose keeps its sample's own stamp


def test_the_travels_integrate_back_to_the_poses_with_exact_arcs() -> None:
    """A calibration rescales the travels and integrates again: with no change they give the replay's final pose."""
    log = synth_log(square_legs(side=0.5), dropout=0.02, spike=0.01, seed=8)
    result = run_batch(log.seq, log.stamp, log.left, log.right)
    assert result.d_left is not None and result.d_right is not None
    x, y, yaw = integrate(result.d_left, result.d_right, OdometryParams().wheel_separation)
    np.testing.assert_allclose(np.column_stack([x, y, yaw])[-1], [result.x[-1], result.y[-1], result.yaw[-1]], atol=1e-9)
    quarter = math.pi / 2 * 0.25  # each wheel's travel for a quarter turn on the spot, 0.5 m apart
    assert integrate(np.array([-quarter]), np.array([quarter]), 0.5)[2][0] == pytest.approx(math.pi / 2)
