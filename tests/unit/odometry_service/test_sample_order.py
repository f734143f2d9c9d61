"""Odometry input with integrity: stamps cannot freeze it, plausible lies cannot steer it, a reset recovers it."""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pytest
import zenoh
from helpers import Child, client_config, free_port, start_robot, wait_for

from blackmetal.bench.synth import square_legs, synth_log
from blackmetal.odometry_service.batch import run_batch
from blackmetal.odometry_service.core import OdometryCore
from blackmetal.odometry_service.errors import OdometryError, SampleRejected, UnstampedSample
from blackmetal.odometry_service.integrator import Odometry
from blackmetal.odometry_service.params import OdometryParams
from blackmetal.odometry_service.replay import read_log, replay_file
from blackmetal.odometry_service.sample_order import unstamped_reason
from blackmetal.schemas import ErrorReport, Keys, Pose, WheelImpulses, decode, encode
from unit.odometry_service.test_core import RecordingOdometryOutput

WALL = 1_800_000_000.0
FWD = (203, -211)  # about 0.2 m/s on both wheels
KEYS = Keys("robot")


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
    odo = Odometry(live=True)
    drive(odo, 1.0)
    x_before = odo.x
    odo.feed(sample(50, 1.0, stamp=WALL + 86_400.0), arrival=1.0)  # one stamp from tomorrow
    xs = drive(odo, 1.0, start_seq=51, start=1.02)
    assert all(b > a for a, b in itertools.pairwise(xs))  # every later sample moves it: not frozen
    assert xs[-1] - x_before == pytest.approx(0.2 * 1.02, rel=0.02)  # and no day of travel either


def test_a_wall_clock_step_back_of_3_s_does_not_freeze_the_pose() -> None:
    odo = Odometry(live=True)
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
    odo = Odometry(live=True)
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
    odo = Odometry(live=True)
    drive(odo, 1.0)
    yaw0 = odo.yaw
    for k in range(20):  # replayed seq 0..19 with new stamps, from the same gateway
        with pytest.raises(SampleRejected, match="out-of-order"):
            odo.feed(sample(k, 1.0 + 0.02 * k, wheels=(-203, -211)), arrival=1.0 + 0.02 * k)
    assert odo.yaw == yaw0  # was 1.19 rad of fake yaw


def test_a_second_gateway_on_the_key_is_rejected_until_the_first_is_gone() -> None:
    odo = Odometry(live=True)
    drive(odo, 1.0)
    with pytest.raises(SampleRejected, match="two gateways"):
        odo.feed(sample(0, 5.0, source="gw-b"), arrival=1.0)
    drive(odo, 0.2, start_seq=50, start=1.0)
    x = odo.x
    odo.feed(sample(0, 9.0, source="gw-b"), arrival=3.0)  # gw-a silent for 1.8 s: a restarted gateway takes over
    assert odo.tally.restarts == 1 and odo.x == x  # a new epoch: nothing integrated across the switch
    odo.feed(sample(1, 9.02, source="gw-b"), arrival=3.02)
    assert odo.x > x


def test_reset_clears_a_poisoned_state_and_refuses_absurd_poses() -> None:
    odo = Odometry()  # a log's rules: live odometry would not take samples without mono
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
    assert batch.restarts == live.tally.restarts == 1 and len(batch.rejected) == 1


def test_delivery_jitter_on_a_loaded_machine_is_never_mistaken_for_a_lie() -> None:
    rng = np.random.default_rng(4)
    odo = Odometry(live=True)
    arrival = mono = 0.0
    fed = 0
    for k in range(2000):  # 40 s at 50 Hz, each delivered 0-300 ms late, in order, polls sometimes 150 ms apart
        mono += 0.15 if k % 97 == 96 else 0.02
        arrival = max(arrival, mono + float(rng.uniform(0.0, 0.3)))
        odo.feed(sample(k, mono), arrival=arrival)  # raises if rejected
        fed += 1
    assert fed == 2000


def test_a_stalled_odometry_follows_again_after_its_backlog() -> None:
    """The odometry stops for 5 s (a stalled host); Zenoh keeps the newest samples and drops the rest.

    The backlog arrives late and starts a new epoch after the dropped ones (a gap); the punctual samples
    after it must pass the arrival check again (they were rejected for good: a fleet robot at 0 poses/s).
    """
    odo = Odometry(live=True)
    drive(odo, 1.0)
    resumed = 6.0
    for k in range(200, 300):  # the 2 s before the end of the stall, delivered at once in order; the 3 s before lost
        odo.feed(sample(k, k * 0.02), arrival=resumed)
    x_backlog = odo.x
    rejected = 0
    for k in range(300, 400):  # punctual again
        try:
            odo.feed(sample(k, k * 0.02), arrival=k * 0.02 + 0.001)
        except SampleRejected:
            rejected += 1
    assert rejected == 0
    assert odo.x - x_backlog == pytest.approx(0.2 * 2.0, rel=0.05)


def test_an_odometry_whose_first_sample_came_late_follows_again_within_a_second() -> None:
    """The first sample of an epoch arrives 2 s late (an odometry starting on a busy host).

    Measured against it, every punctual sample after it looks 2 s ahead and was rejected for good;
    after RESYNC_S of them at one steady offset a new epoch starts, reported, and the pose follows.
    """
    odo = Odometry(live=True)
    odo.feed(sample(0, 0.0), arrival=2.0)
    rejected = 0
    for k in range(100, 300):  # the samples in between were dropped; 4 s of punctual ones
        try:
            odo.feed(sample(k, k * 0.02), arrival=k * 0.02 + 0.001)
        except SampleRejected:
            rejected += 1
    assert 45 <= rejected <= 55  # RESYNC_S at 50 Hz, then no more
    assert any("measured again" in event for event in odo.events), odo.events
    assert odo.x == pytest.approx(0.2 * (200 - rejected - 1) * 0.02, rel=0.05)


def test_a_forger_claiming_ever_more_time_never_earns_a_resync() -> None:
    """Creep (each forged sample a little further ahead) keeps moving the offset: the run restarts, nothing is taken."""
    odo = Odometry(live=True)
    drive(odo, 1.0)
    x_before, accepted = odo.x, 0
    for k in range(50, 250):  # 4 s of forged samples at 50 Hz, each claiming 0.12 s more than the last
        t = 1.0 + (k - 50) * 0.02
        try:
            odo.feed(sample(k, t + (k - 49) * 0.12), arrival=t)
            accepted += 1
        except SampleRejected:
            pass
    assert odo.x - x_before < 0.2 * 0.6 + 0.01  # at most the epoch's settling budget, never the 24 s claimed
    assert accepted <= 6


# ------------------------------------------------- live input without mono/source: a forger beside the gateway

#: Delivery delay of the honest gateway's samples in the fake-clock scenes (s).
DELAY = 0.003


def forged(seq: int, stamp: float, wheels: tuple[int, int] = FWD) -> WheelImpulses:
    """What a foreign publisher (or a gateway older than the odometry) sends: no ``mono``, no ``source``."""
    return WheelImpulses(seq=seq, stamp=stamp, left=wheels[0], right=wheels[1])


class Scene:
    """The odometry core on a fake clock beside a live gateway, and a reference core fed the gateway's samples only."""

    def __init__(self) -> None:
        self.out = RecordingOdometryOutput()
        self.core = OdometryCore(OdometryParams(), KEYS, self.out, wallclock=lambda: WALL)
        self.reference_out = RecordingOdometryOutput()
        self.reference = OdometryCore(OdometryParams(), KEYS, self.reference_out, wallclock=lambda: WALL)
        self.seq = 0
        self.now = 0.0

    def run(self, seconds: float, forgeries: Sequence[tuple[float, WheelImpulses]] = ()) -> None:
        """``seconds`` of the gateway at 50 Hz (``mono``, ``source``, delivered DELAY late), the forgeries in between at their times."""
        events: list[tuple[float, WheelImpulses, bool]] = [(at, message, False) for at, message in forgeries]
        for _ in range(round(seconds * 50)):
            mono = self.seq * 0.02
            events.append((mono + DELAY, sample(self.seq, mono), True))
            self.seq += 1
        for at, message, honest in sorted(events, key=lambda event: event[0]):
            self.now = at
            for core in (self.core, self.reference) if honest else (self.core,):
                core.on_impulses(encode(message), at)
                core.tick(at)

    def settle(self) -> None:
        """Let the rate-limited reports' summaries out."""
        for later in (2.0, 4.0):
            self.core.tick(self.now + later)

    def assert_rejected_and_reported(self, count: int) -> None:
        """``count`` samples rejected, each reported (published, or counted in a later report) with what to upgrade."""
        assert self.core.rejected == count
        errors = self.out.errors
        assert errors and {e.key for e in errors} == {KEYS.impulses} and {e.source for e in errors} == {"odometry"}
        published = [e for e in errors if e.reason == unstamped_reason(None, None)]
        assert len(published) + sum(e.suppressed for e in errors) == count
        assert all(e.reason == unstamped_reason(None, None) or "rate-limited" in e.reason for e in errors)

    def assert_pose_follows_the_gateway_only(self) -> None:
        assert self.out.poses == self.reference_out.poses
        assert self.core.latest() == self.reference.latest()


def test_the_reason_says_what_is_missing_and_what_to_upgrade() -> None:
    assert unstamped_reason(None, None) == (
        "impulses without mono and source: the sender is a gateway older than this odometry or a foreign publisher; "
        "live odometry needs a gateway that stamps mono and source (upgrade the gateway; logs without them still replay)"
    )
    assert unstamped_reason(1.0, None).startswith("impulses without source:")
    assert unstamped_reason(None, "gw-a").startswith("impulses without mono:")


def test_unstamped_creep_beside_a_live_gateway_is_rejected_and_reported() -> None:
    """200 samples at 1 kHz claiming 0.49 s each, without mono/source: rejected (they moved the pose +81.8 m)."""
    scene = Scene()
    scene.run(0.5)
    creep = [(0.5 + 0.001 * k, forged(25 + k, WALL + 0.5 + 0.49 * (k + 1), wheels=(850, -885))) for k in range(200)]
    scene.run(0.5, creep)
    scene.settle()
    scene.assert_rejected_and_reported(200)
    scene.assert_pose_follows_the_gateway_only()
    assert scene.core.latest().x == pytest.approx(0.2 * 0.98, rel=0.02)


def test_an_unstamped_sample_a_day_ahead_beside_a_live_gateway_is_rejected_and_reported() -> None:
    """One sample without mono/source stamped a day ahead: rejected (it froze the pose)."""
    scene = Scene()
    scene.run(1.0)
    scene.run(1.0, [(1.001, forged(50, WALL + 86_400.0))])
    scene.settle()
    scene.assert_rejected_and_reported(1)
    scene.assert_pose_follows_the_gateway_only()
    assert scene.core.latest().x == pytest.approx(0.2 * 1.98, rel=0.02)  # not frozen


def test_unstamped_old_sequence_numbers_with_fresh_stamps_beside_a_live_gateway_are_rejected_and_reported() -> None:
    """Seq 0..19 again, fresh stamps, turning in place, without mono/source: rejected (they turned the pose 1.22 rad)."""
    scene = Scene()
    scene.run(1.0)
    replayed = [(1.01 + 0.02 * k, forged(k, WALL + 1.0 + 0.02 * k, wheels=(-203, -211))) for k in range(20)]
    scene.run(1.0, replayed)
    scene.settle()
    scene.assert_rejected_and_reported(20)
    scene.assert_pose_follows_the_gateway_only()
    assert abs(scene.core.latest().yaw) < 1e-3


@pytest.mark.parametrize(("mono", "source", "missing"), [(None, "gw-a", "mono"), (1.0, None, "source"), (None, None, "mono and source")])
def test_live_odometry_requires_both_mono_and_source(mono: float | None, source: str | None, missing: str) -> None:
    """Each switched a check off: without mono no arrival check (and wall-stamp intervals), without source no one-gateway rule."""
    odo = Odometry(live=True)
    drive(odo, 1.0)
    x = odo.x
    with pytest.raises(UnstampedSample, match=f"^impulses without {missing}:"):
        odo.feed(WheelImpulses(seq=50, stamp=WALL + 86_400.0, left=850, right=-885, mono=mono, source=source), arrival=1.0)
    drive(odo, 0.2, start_seq=50, start=1.0)
    assert odo.x == pytest.approx(x + 0.2 * 0.2, rel=0.02)
    with pytest.raises(ValueError, match="arrival"):  # live input without its arrival time is a caller's bug
        odo.feed(sample(60, 1.2))


def test_replay_still_reads_a_log_without_mono_and_source(tmp_path: Path) -> None:
    log = synth_log(square_legs(side=0.5), seed=3)
    path = tmp_path / "old-gateway.jsonl"
    path.write_bytes(log.jsonl())
    assert b'"mono"' not in path.read_bytes() and b'"source"' not in path.read_bytes()
    assert read_log(path.read_bytes()).mono is None
    result = replay_file(path)
    assert len(result) == len(log) and result.rejected == []
    streamed = Odometry()  # a log's rules, sample by sample
    poses = [streamed.feed(m) for m in log.messages()]
    assert np.allclose(result.x, [p.x for p in poses], atol=1e-9) and np.allclose(result.y, [p.y for p in poses], atol=1e-9)


@pytest.mark.integration
def test_a_forger_beside_a_live_gateway_on_zenoh_cannot_move_the_pose(children: list[Child]) -> None:
    """Creep, a stamp a day ahead and old sequence numbers, all without mono/source, while the robot drives."""
    zport = free_port()
    start_robot(children, zport, gateway_args=("--cmd-timeout", "1.0", "--poll-hz", "50"))
    with zenoh.open(client_config(zport)) as session:
        honest: list[WheelImpulses] = []
        errors: list[ErrorReport] = []

        def on_impulses(s: zenoh.Sample) -> None:
            message = decode(WheelImpulses, s.payload.to_bytes())
            if message.source is not None:  # this session hears its own forgeries too
                honest.append(message)

        session.declare_subscriber(KEYS.impulses, on_impulses)
        session.declare_subscriber(KEYS.errors, lambda s: errors.append(decode(ErrorReport, s.payload.to_bytes())))
        forger = session.declare_publisher(KEYS.impulses)
        wait_for(lambda: len(honest) > 10, what="impulses from the gateway")

        def get(key: str) -> Pose:
            replies = [r.ok for r in session.get(key, timeout=5) if r.ok is not None]
            assert replies, f"no answer on {key}"
            return decode(Pose, replies[0].payload.to_bytes())

        def creep() -> None:  # 200 samples at 1 kHz, each claiming 0.49 s
            seq, t0 = honest[-1].seq + 1, time.time()
            for k in range(200):
                forger.put(encode(forged(seq + k, t0 + 0.49 * (k + 1), wheels=(850, -885))))
                time.sleep(0.001)

        def future() -> None:  # one sample a day ahead
            forger.put(encode(forged(honest[-1].seq + 1, time.time() + 86_400.0)))

        def replay() -> None:  # old sequence numbers, fresh stamps, turning in place
            for k in range(20):
                forger.put(encode(forged(k, time.time(), wheels=(-203, -211))))
                time.sleep(0.02)

        attacks: dict[int, Callable[[], None]] = {5: creep, 15: future, 25: replay}
        get(KEYS.odometry_reset)
        start_truth = get(KEYS.sim_truth)
        for step in range(40):  # 4 s of teleop at 10 Hz: straight, then an arc; the forger strikes in between
            v, w = (0.3, 0.0) if step < 20 else (0.2, 0.5)
            session.put(KEYS.cmd_vel, encode_twist(v, w))
            attacks.get(step, lambda: None)()
            time.sleep(0.1)
        wait_for(lambda: abs(get(KEYS.sim_truth).v) < 1e-9 and abs(get(KEYS.pose).v) < 1e-9, timeout=10, what="the robot to stand still")
        truth, pose = get(KEYS.sim_truth), get(KEYS.pose)

        def accounted() -> int:
            published = sum(e.reason == unstamped_reason(None, None) for e in errors)
            return published + sum(e.suppressed for e in errors if e.key == KEYS.impulses and e.source == "odometry")

        wait_for(lambda: accounted() >= 221, what="every forgery reported (published or counted as rate-limited)")
    dx, dy = truth.x - start_truth.x, truth.y - start_truth.y
    c, s = math.cos(-start_truth.yaw), math.sin(-start_truth.yaw)
    rel_x, rel_y, rel_yaw = c * dx - s * dy, s * dx + c * dy, math.remainder(truth.yaw - start_truth.yaw, math.tau)
    assert math.hypot(rel_x, rel_y) > 0.5, "the robot did not move"
    assert math.hypot(pose.x - rel_x, pose.y - rel_y) < 0.02, (pose, rel_x, rel_y)  # was +81.8 m, or frozen
    assert abs(math.remainder(pose.yaw - rel_yaw, math.tau)) < 0.03  # was 1.22 rad off


def encode_twist(v: float, w: float) -> bytes:
    return b'{"linear": {"x": %r}, "angular": {"z": %r}}' % (v, w)
