"""The telemetry figures' rows: poll rate against the asked rate, memory against a bare zenoh process."""

from __future__ import annotations

from blackmetal.bench.telemetry import MEMORY, POLL, RECORDER


def test_the_rows_say_met_or_missed() -> None:
    poll = {100: {"rate_hz": 99.5, "worst_gap_ms": 25.0, "ratio": 0.995, "worst_gap_periods": 2.5},
            200: {"rate_hz": 150.0, "worst_gap_ms": 40.0, "ratio": 0.75, "worst_gap_periods": 8.0}}  # fmt: skip
    fine, short = POLL.rows({"poll": poll})
    assert fine == ("poll at 100 Hz", "99.5 Hz, worst gap 25.0 ms", "asked 100 Hz", "99.5% (>= 98%), gap 2.50 periods (<= 3): met")
    assert short[3].endswith(": MISSED")
    (rec,) = RECORDER.rows({"recorder": {100: {"cpu_pct": 3.0, "bytes_per_s": 12_000.0}}})
    assert rec == ("recorder at 100 Hz polling", "CPU 3.0% of a core, 12.0 kB/s", "-", "report")
    memory = {"seconds": 60.0, "gateway_mb": 70.0, "odometry_mb": 60.0, "bare_zenoh_mb": 40.0, "gateway_over_bare_mb": 30.0,
              "odometry_over_bare_mb": 20.0, "gateway_cpu_pct": 5.0, "odometry_cpu_pct": 2.0}  # fmt: skip
    rss, cpu = MEMORY.rows({"memory": memory})
    assert rss[3] == "+30.0 / +20.0 MB (<= +40 MB: met)" and cpu[1] == "gateway 5.0%, odometry 2.0% of a core"
