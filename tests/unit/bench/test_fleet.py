"""The fleet table: one row per size, memory per added robot against the smallest fleet."""

from __future__ import annotations

from typing import Any

from blackmetal.bench.fleet import fleet_table


def _run(robots: int, rss: float, **extra: Any) -> dict[str, Any]:
    return {"robots": robots, "cpu_services": 0.5, "cpu": {"router": 0.1, "gateway": 0.3, "odometry": 0.1, "sim": 0.2},
            "rss_services_mb": rss, "pose_hz_min": 49.0, "pose_hz_median": 50.0, "messages_per_s": 400.0,
            "cmd_vel_ms": {"p50_ms": 0.5, "p99_ms": 2.0}, "estop_ms": {"p50_ms": 0.6, "p99_ms": 2.5, **extra}}  # fmt: skip


def test_one_row_per_size() -> None:
    lines = fleet_table([_run(1, 100.0), _run(11, 120.0, missing=2)]).splitlines()
    assert lines[0].startswith("robots | CPU router+gateway+odometry (sim apart)") and set(lines[1]) == {"-"}
    assert lines[2].startswith("     1 | 0.50 cores (router 0.10, gateway 0.30, odometry 0.10; sim 0.20) | 100 MB, - |")
    assert "| 120 MB, 2.00 MB |" in lines[3] and lines[3].endswith("0.60/2.50 ms (2 engages without their own EMG_STOP)")
    assert len(lines) == 4  # no views: no second table
