"""The governor's vocabulary: the re-send pacing and the e-stopped state's re-checks."""

from __future__ import annotations

import math

from blackmetal.gateway.safety_states import RETRY_CAP_S, STOP_GRACE_S, EStopped, Robot, retry_delay


def test_re_sends_pause_5_ms_doubling_to_at_most_250_ms() -> None:
    assert [retry_delay(n) for n in (1, 2, 3)] == [0.005, 0.01, 0.02]
    assert retry_delay(0) == 0.005 and retry_delay(50) == RETRY_CAP_S == 0.25


def test_an_emg_stop_is_asked_again_only_while_written_and_the_wheels_turn() -> None:
    pending = EStopped(Robot(moving=True), emg_at=1.0)
    assert pending.recheck_at == math.inf  # still to go out
    written = EStopped(Robot(moving=True), emg_at=1.0, emg_pending=False)
    assert written.recheck_at == 1.0 + STOP_GRACE_S
    assert EStopped(Robot(), emg_at=1.0, emg_pending=False).recheck_at == math.inf  # the wheels stand
    again = written.emg_again(2.0).emg_again(3.0)
    assert again.emg_pending and again.emg_resends == 2 and again.emg_at == 3.0 + retry_delay(2)
