"""The command path's rows: the e-stop under a flood and the flood itself, from made-up results."""

from __future__ import annotations

from blackmetal.bench.command_path import ESTOP_FLOOD, FLOOD, _json_twist


def test_a_twist_of_a_given_speed() -> None:
    assert _json_twist(-0.0005) == b'{"linear":{"x":-0.000500}}'


def test_the_rows() -> None:
    flooded = {"flooders": 3, "p50_ms": 1.0, "p99_ms": 5.0, "max_ms": 120.0, "n": 100, "lost": 1}
    ((label, measured, _, verdict),) = ESTOP_FLOOD.rows({"estop_under_flood_ms": flooded})
    assert label == "e-stop under 3 full-speed flooders, p50 / p99 / max" and measured == "1.00 / 5.00 / 120.00 ms"
    assert verdict == "max <= 100 ms: MISSED; 100 samples, 1 without EMG_STOP"
    flood = {"sent_hz": 5000.0, "rss_before_mb": 50.0, "rss_after_mb": 51.0, "last_command_latency_ms": 0.8,
             "rss_growth_mb": 1.0, "commands_at_robot": 900, "sent": 25001}  # fmt: skip
    ((label, measured, _, verdict),) = FLOOD.rows({"flood": flood})
    assert label == "cmd_vel flood 5.0 kHz" and measured == "RSS 50.0 -> 51.0 MB; last command after 0.80 ms"
    assert verdict == "+1.0 MB; 900 of 25001 puts sent on (latest wins)"
