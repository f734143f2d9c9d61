"""The odometry service's core, with recorded output and an injected clock."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import msgspec
import pytest

from blackmetal.bench.synth import SynthLog, square_legs, synth_log
from blackmetal.odometry_service.core import DROPPED_REPORT_PERIOD_S, OdometryCore
from blackmetal.odometry_service.params import OdometryParams
from blackmetal.schemas import ErrorReport, Keys, PayloadError, Pose, WheelImpulses, encode


@dataclass
class RecordingOdometryOutput:
    """An odometry output that keeps everything."""

    poses: list[Pose] = field(default_factory=list)
    errors: list[ErrorReport] = field(default_factory=list)

    def __call__(self, message: Pose | ErrorReport) -> None:
        (self.poses if isinstance(message, Pose) else self.errors).append(message)  # type: ignore[arg-type]


def service() -> tuple[OdometryCore, RecordingOdometryOutput]:
    out = RecordingOdometryOutput()
    return OdometryCore(OdometryParams(), Keys("robot"), out), out


def live(log: SynthLog, pace: float = 1.0) -> list[WheelImpulses]:
    """The log's samples as a live gateway stamps them (``mono``, ``source``); ``pace`` < 1 squeezes their ``mono``."""
    start = float(log.stamp[0])
    return [msgspec.structs.replace(m, mono=(m.stamp - start) * pace, source="gw-test") for m in log.messages()]


def test_every_sample_publishes_a_pose_and_bad_input_is_reported() -> None:
    svc, out = service()
    messages = live(synth_log(square_legs(side=0.5), seed=1))
    for msg in messages[:200]:
        assert msg.mono is not None
        svc.on_impulses(encode(msg) + b"\n", msg.mono)
    assert len(out.poses) == 200
    for bad in (b"", b"garbage", b'{"seq":1}', b'{"seq":-1,"stamp":1,"left":0,"right":0}', b'{"seq":5,"stamp":NaN,"left":0,"right":0}'):
        svc.on_impulses(bad, 100.0)
    svc.on_impulses(encode(messages[150]), 100.0)  # a duplicate from the past
    assert len(out.poses) == 200
    assert svc.rejected == 6
    assert all(e.source == "odometry" and e.reason for e in out.errors)
    assert any("out-of-order" in e.reason for e in out.errors)


def test_reset_to_zero_or_to_a_given_pose() -> None:
    svc, _ = service()
    for msg in live(synth_log(square_legs(side=0.5), seed=1))[:300]:
        assert msg.mono is not None
        svc.on_impulses(encode(msg), msg.mono)
    assert svc.latest().x != 0.0
    assert svc.on_reset(None, 100.0).x == 0.0
    pose = svc.on_reset(b'{"x": 1.5, "y": -2, "yaw": 4.0}', 100.0)
    assert (pose.x, pose.y) == (1.5, -2.0) and pose.yaw == pytest.approx(4.0 - 2 * math.pi)
    with pytest.raises(PayloadError):
        svc.on_reset(b'{"x": "far"}', 100.0)


def test_the_core_publishes_summaries_and_dropped_counts_in_its_own_tick() -> None:
    svc, out = service()
    assert svc.next_deadline() == math.inf
    for _ in range(25):  # a flood at one instant: the burst is published, the rest is summarised later
        svc.on_impulses(b"garbage", 10.0)
    assert len(out.errors) == 10 and svc.rejected == 25
    deadline = svc.next_deadline()
    assert 10.0 < deadline < math.inf
    svc.tick(deadline - 0.001)
    assert len(out.errors) == 10
    svc.tick(deadline + 5.0)
    assert out.errors[-1].suppressed == 15 and "rate-limited" in out.errors[-1].reason
    assert svc.next_deadline() == math.inf
    svc.on_dropped(3, 20.0)
    svc.on_dropped(4, 20.1)
    assert svc.next_deadline() <= 20.1
    svc.tick(20.1)
    assert out.errors[-1].reason.startswith("7 impulse samples dropped")
    svc.on_dropped(2, 20.2)  # at most one dropped-count report a period, the counts summed
    assert svc.next_deadline() == pytest.approx(20.1 + DROPPED_REPORT_PERIOD_S)
    svc.tick(20.3)
    assert out.errors[-1].reason.startswith("7 ")
    svc.tick(20.1 + DROPPED_REPORT_PERIOD_S)
    assert out.errors[-1].reason.startswith("2 impulse samples dropped")
    assert svc.next_deadline() == math.inf
