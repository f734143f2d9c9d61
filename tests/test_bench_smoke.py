"""``blackmetal bench --quick`` runs end to end, so the command cannot rot. No figure is asserted."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytestmark = pytest.mark.integration


def test_bench_quick_produces_every_figure(tmp_path) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "bench.json"
    proc = subprocess.run(
        [sys.executable, "-m", "blackmetal", "bench", "--quick", "--json", str(out)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    for row in (
        "cmd_vel -> robot socket p50",
        "impulse -> Pose at client p50",
        "poll at 200 Hz",
        "replay",
        "RSS after",
        "CPU at 100 Hz",
        "cmd_vel flood",
        "ROS /cmd_vel -> robot p50",
        "/odom rate at 100 Hz",
        "replay from MCAP",
        "batch odometry, parsed columns",
        "calibration of a 2 m square pair",
        "recorder at 200 Hz polling",
    ):
        assert row in proc.stdout
    figures = json.loads(out.read_text())
    assert set(figures) >= {"cmd_vel_to_robot_ms", "zenoh_hop_ms", "impulse_to_pose_ms", "two_hops_ms", "poll", "replay", "memory", "flood"}
    assert figures["poll"]["100"]["rate_hz"] > 0 and figures["replay"]["replay_per_s"] > 0
