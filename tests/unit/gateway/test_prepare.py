"""PREPARE_WHEEL_CONTROLLER's re-sends, on a fake clock."""

from __future__ import annotations

import math

from blackmetal.gateway.prepare import PrepareRetry
from blackmetal.gateway.safety_states import retry_delay


def test_a_dropped_prepare_is_sent_again_once_after_a_growing_pause() -> None:
    prepare = PrepareRetry()
    assert prepare.next_deadline() == math.inf and not prepare.due(0.0)
    prepare.dropped(1.0)
    prepare.dropped(1.001)  # a re-send is planned already
    assert prepare.next_deadline() == 1.0 + retry_delay(1) and not prepare.due(1.001)
    assert prepare.due(1.0 + retry_delay(1)) and not prepare.due(2.0)  # once per planned re-send
    prepare.dropped(2.0)
    assert prepare.next_deadline() == 2.0 + retry_delay(2)


def test_a_new_connection_starts_over_and_a_dead_one_plans_nothing() -> None:
    prepare = PrepareRetry()
    prepare.dropped(0.0)
    prepare.cancel()
    assert prepare.next_deadline() == math.inf and prepare.attempts == 1
    prepare.reset()
    prepare.dropped(5.0)
    assert prepare.next_deadline() == 5.0 + retry_delay(1)
    prepare.taken()
    assert prepare.attempts == 0
