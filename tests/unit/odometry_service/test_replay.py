"""The replay core: a log's columns, its bad lines named, every pose as the live service publishes it."""

from __future__ import annotations

import io
import math
import subprocess
import sys

import numpy as np
import pytest
from helpers import exact_pose

from blackmetal.bench.synth import square_legs, synth_log
from blackmetal.odometry_service.errors import ReplayError
from blackmetal.odometry_service.integrator import Odometry
from blackmetal.odometry_service.replay import final_pose, read_log, replay_file, summary, write_poses
from blackmetal.schemas import Pose, decode


def test_a_log_replays_in_process_to_the_streaming_poses(tmp_path) -> None:  # type: ignore[no-untyped-def]
    log = synth_log(square_legs(side=0.5), dropout=0.01, seed=3)
    path = tmp_path / "log.jsonl"
    path.write_bytes(log.jsonl())
    result = replay_file(path)
    odo = Odometry()
    streamed = [odo.feed(m) for m in log.messages()]
    assert len(result) == len(streamed)
    assert final_pose(result).x == pytest.approx(streamed[-1].x, abs=1e-9)
    out = io.BytesIO()
    write_poses(result, out)
    lines = out.getvalue().splitlines()
    assert len(lines) == len(streamed) and decode(Pose, lines[-1]).y == pytest.approx(streamed[-1].y, abs=1e-9)
    assert summary(result).startswith(f"{len(result)} samples, 0 rejected, ")


def test_an_empty_log_ends_at_the_origin_and_bad_logs_name_the_line(tmp_path) -> None:  # type: ignore[no-untyped-def]
    assert (final_pose(read_log(b"").replay()).x, final_pose(read_log(b"").replay()).yaw) == (0.0, 0.0)
    log = read_log(b'{"seq":0,"stamp":1.0,"left":3,"right":-3,"mono":0.5,"source":"gw"}\n\n')
    assert log.mono is not None and log.sources == ["gw"] and np.array_equal(log.left, [3.0])
    with pytest.raises(ReplayError, match="line 2: not a WheelImpulses"):
        read_log(b'{"seq":0,"stamp":1.0,"left":0,"right":0}\n{"seq":1}\n')
    with pytest.raises(ReplayError, match="line 1: stamp must be finite"):
        read_log(b'{"seq":-1,"stamp":1.0,"left":0,"right":0}\n')
    with pytest.raises(ReplayError, match="beyond 2\\*\\*53"):
        read_log(b'{"seq":0,"stamp":1.0,"left":9007199254740993,"right":0}\n')
    with pytest.raises(ReplayError, match="cannot read"):
        replay_file(tmp_path / "missing.jsonl")


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
