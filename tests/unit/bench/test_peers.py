"""The bench's percentiles: p50, p99 and max in ms, and no figure from no sample."""

from __future__ import annotations

import pytest

from blackmetal.bench.peers import percentiles


def test_percentiles_in_ms() -> None:
    samples = [i / 1000 for i in range(1, 101)]  # 1 .. 100 ms
    assert percentiles(samples) == pytest.approx({"p50_ms": 51.0, "p99_ms": 100.0, "max_ms": 100.0, "n": 100})
    with pytest.raises(TimeoutError, match="not one sample arrived"):
        percentiles([])
