"""Odometry service: its core with recorded output, its host on a loop, the replay command, and the full chain on Zenoh."""

from __future__ import annotations

import asyncio
import json
import math
import signal
import subprocess
import sys
import time

import msgspec
import numpy as np
import pytest
import zenoh
from helpers import Child, client_config, exact_pose, free_port, start_robot, wait_for, zenoh_listen_args

from blackmetal.bench.synth import SynthLog, square_legs, synth_log
from blackmetal.odometry_service.core import DROPPED_REPORT_PERIOD_S, OdometryCore, RecordingOdometryOutput
from blackmetal.odometry_service.host import OdometryHost
from blackmetal.odometry_service.integrator import Odometry
from blackmetal.odometry_service.params import OdometryParams
from blackmetal.schemas import Keys, PayloadError, Pose, WheelImpulses, decode, encode


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


def test_the_host_stamps_inputs_and_runs_the_cores_timers_on_the_loop() -> None:
    async def scenario() -> RecordingOdometryOutput:
        svc, out = service()
        svc.reporter.summary_period = 0.02  # summaries come from the core's tick, not from a host timer
        host = OdometryHost(svc)
        stop = asyncio.Event()
        dropped = [0]
        running = asyncio.create_task(host.run(stop, dropped=lambda: dropped[0]))
        await asyncio.sleep(0)
        for msg in live(synth_log(square_legs(side=0.5), seed=1), pace=1e-3)[:20]:  # delivered at once: mono barely moves
            host.on_impulses(encode(msg))
        dropped[0] = 5  # the bounded input dropped five samples while these waited
        host.on_impulses(b"garbage")
        await asyncio.sleep(0.01)  # the core's tick reports them at once
        for _ in range(12):
            host.on_impulses(b"garbage")
        assert host.on_reset(None).x == 0.0
        for _ in range(200):  # a token comes back after 1/rate = 0.2 s; then the next tick summarises
            if any("were rate-limited" in e.reason for e in out.errors):
                break
            await asyncio.sleep(0.01)
        stop.set()
        await running
        return out

    out = asyncio.run(scenario())
    assert len(out.poses) == 20
    reasons = [e.reason for e in out.errors]
    assert any(r.startswith("5 impulse samples dropped") for r in reasons)
    assert any("were rate-limited" in r for r in reasons)


def test_replay_command_prints_the_final_pose_and_writes_every_pose(tmp_path) -> None:  # type: ignore[no-untyped-def]
    legs = square_legs()
    log = synth_log(legs, dropout=0.01, spike=0.005, seed=11)
    path = tmp_path / "square.jsonl"
    path.write_bytes(log.jsonl())
    out = tmp_path / "poses.jsonl"
    proc = subprocess.run(
        [sys.executable, "-m", "blackmetal", "replay", str(path), "-o", str(out)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    final = decode(Pose, proc.stdout.strip().splitlines()[-1])
    exact = exact_pose(legs)
    assert math.hypot(final.x - exact[0], final.y - exact[1]) < 0.010
    assert abs(math.remainder(final.yaw - exact[2], math.tau)) < 0.010
    assert "spikes" in proc.stderr
    # every pose equals what the live (streaming) service would have published
    odo = Odometry()
    streamed = [odo.feed(m) for m in log.messages()]
    replayed = [decode(Pose, line) for line in out.read_bytes().splitlines()]
    assert len(replayed) == len(streamed)
    got = np.array([(p.x, p.y, p.yaw, p.v, p.w) for p in replayed])
    want = np.array([(p.x, p.y, p.yaw, p.v, p.w) for p in streamed])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


def test_replay_names_a_bad_line(tmp_path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "bad.jsonl"
    path.write_bytes(b'{"seq":0,"stamp":1.0,"left":0,"right":0}\n{"seq":1,"stamp":"x","left":0,"right":0}\n')
    proc = subprocess.run([sys.executable, "-m", "blackmetal", "replay", str(path)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "line 2" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.integration
def test_drive_the_simulator_and_the_pose_follows_the_truth(children: list[Child]) -> None:
    zport = free_port()
    _, _, odometry = start_robot(children, zport, gateway_args=("--cmd-timeout", "1.0", "--poll-hz", "50"))
    with zenoh.open(client_config(zport)) as session:
        poses: list[Pose] = []
        session.declare_subscriber("robot/pose", lambda s: poses.append(decode(Pose, s.payload.to_bytes())))
        wait_for(lambda: len(poses) > 10, what="poses from the odometry service")

        def get(key: str, payload: bytes | None = None) -> Pose:
            replies = [r for r in session.get(key, payload=payload, timeout=5) if r.ok is not None]
            assert replies, f"no answer on {key}"
            return decode(Pose, replies[0].ok.payload.to_bytes())

        def drive(v: float, w: float, seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:  # a teleop-like stream at 10 Hz
                session.put("robot/cmd_vel", json.dumps({"linear": {"x": v}, "angular": {"z": w}}))
                time.sleep(0.1)

        def stopped() -> bool:
            return abs(get("robot/sim/truth").v) < 1e-9 and abs(get("robot/pose").v) < 1e-9

        get("robot/odometry/reset")
        start_truth = get("robot/sim/truth")
        for v, w, seconds in [(0.3, 0.0, 3.0), (0.0, 0.8, 2.0), (0.25, 0.4, 3.0), (0.0, 0.0, 0.5), (0.2, -0.6, 2.5)]:
            drive(v, w, seconds)
        wait_for(stopped, timeout=10, what="the robot and the odometry to stand still")
        truth = get("robot/sim/truth")
        pose = get("robot/pose")
        # the truth started where it was at the reset; odometry started at zero
        dx, dy = truth.x - start_truth.x, truth.y - start_truth.y
        c, s = math.cos(-start_truth.yaw), math.sin(-start_truth.yaw)
        rel_x, rel_y = c * dx - s * dy, s * dx + c * dy
        rel_yaw = math.remainder(truth.yaw - start_truth.yaw, math.tau)
        travelled = 0.3 * 3 + 0.25 * 3 + 0.2 * 2.5
        assert math.hypot(rel_x, rel_y) > 0.5, "the robot did not move"
        print(
            f"odometry vs truth: {1000 * math.hypot(pose.x - rel_x, pose.y - rel_y):.1f} mm, {1000 * abs(math.remainder(pose.yaw - rel_yaw, math.tau)):.1f} mrad"
        )
        assert math.hypot(pose.x - rel_x, pose.y - rel_y) < 0.02, (pose, rel_x, rel_y, travelled)
        assert abs(math.remainder(pose.yaw - rel_yaw, math.tau)) < 0.03
        alive = [str(r.ok.key_expr) for r in session.liveliness().get("robot/alive/*", timeout=5) if r.ok is not None]
        assert "robot/alive/odometry" in alive and "robot/alive/gateway" in alive
    start = time.monotonic()
    assert odometry.stop(signal.SIGTERM) == 0
    assert time.monotonic() - start < 2.0


@pytest.mark.integration
def test_hostile_impulses_and_resets_on_zenoh(children: list[Child]) -> None:
    zport = free_port()
    odometry = Child(["-m", "blackmetal.odometry_service", *zenoh_listen_args(zport)])
    children.append(odometry)
    odometry.ready()
    with zenoh.open(client_config(zport)) as session:
        errors: list[dict[str, object]] = []
        session.declare_subscriber("robot/errors", lambda s: errors.append(json.loads(s.payload.to_bytes())))
        wait_for(lambda: [r for r in session.get("robot/pose", timeout=5) if r.ok is not None], what="the pose queryable")
        block = zenoh.CongestionControl.BLOCK
        for payload in (b"\x00garbage", b'{"seq":1,"stamp":Infinity,"left":0,"right":0}', b"A" * (1 << 20)):
            session.put("robot/wheels/impulses", payload, congestion_control=block)
        wait_for(lambda: len(errors) >= 3, what="three error reports")
        assert {e["key"] for e in errors} == {"robot/wheels/impulses"}
        replies = list(session.get("robot/odometry/reset", payload=b'{"x":"no"}', timeout=5))
        assert replies and replies[0].err is not None and b"invalid PoseReset" in replies[0].err.payload.to_bytes()
        replies = list(session.get("robot/odometry/reset", payload=b'{"x":1.0,"yaw":0.5}', timeout=5))
        pose = decode(Pose, replies[0].ok.payload.to_bytes())
        assert (pose.x, pose.yaw) == (1.0, 0.5)
        assert odometry.proc.poll() is None
