"""The gateway's counters: each is a field of its health report, where the core passes them as they are."""

from __future__ import annotations

import dataclasses

from blackmetal.gateway.health import Counters
from blackmetal.schemas import GatewayHealth


def test_every_counter_is_a_field_of_the_health_report() -> None:
    names = [field.name for field in dataclasses.fields(Counters)]
    assert set(names) <= set(GatewayHealth.__struct_fields__)
    assert vars(Counters()) == dict.fromkeys(names, 0)
