"""The offline figures: the arbiter's cost on a fake clock, and the rows the table prints of them."""

from __future__ import annotations

from blackmetal.bench.offline import ARBITER, CALIBRATION, REPLAY, arbiter_cost


def test_the_arbiters_cost_is_measured_against_the_cores_whole_handling() -> None:
    cost = arbiter_cost(200, rounds=1)
    assert cost["arbiter_us"] > 0 and cost["core_us"] > 0 and cost["arbiter_share"] > 0
    (five, locks) = ARBITER.rows({"arbiter": cost})
    assert five[0] == "arbiter per command (5 sources)" and locks[0] == "arbiter per command (+3 locks)"


def test_the_rows_of_replay_and_calibration() -> None:
    replay = {"samples": 1000, "replay_per_s": 2e6, "replay_min_per_s": 1.5e6, "replay_max_per_s": 2.5e6, "stream_per_s": 5e4,
              "ratio": 40.0, "mcap": {"skipped": "pip install 'blackmetal[record]'"}}  # fmt: skip
    first, mcap = REPLAY.rows({"replay": replay})
    assert first == ("replay (1000 samples, file read)", "2.00 M/s [1.50-2.50]", "streaming 50 k/s", "40x (>= 1 M/s: met; >= 20x: met)")
    assert mcap == ("replay from MCAP (same samples)", "skipped, pip install 'blackmetal[record]'", "", "")
    calibration = {"samples": 10, "batch_per_s": 5e6, "batch_faulty_per_s": 4e6, "evaluation_per_s": 2e7, "fit_s": 0.25,
                   "fit_steps": 100, "fit_evaluations": 30}  # fmt: skip
    batch, fit = CALIBRATION.rows({"calibration": calibration})
    assert batch[3] == "(>= 10 M/s: MISSED; evaluation: met)" and fit[1] == "250 ms (100 steps, 30 evaluations)"
