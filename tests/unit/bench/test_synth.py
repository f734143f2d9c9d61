"""Synthetic logs: a square closes, no count is lost, dropouts are single, and JSON lines match the messages."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import exact_pose

from blackmetal.bench.synth import square_legs, synth_log


def test_a_square_ends_where_it_started() -> None:
    x, y, yaw = exact_pose(square_legs(side=1.0))
    assert (x, y) == pytest.approx((0.0, 0.0), abs=1e-9) and abs(np.remainder(yaw, 2 * np.pi)) == pytest.approx(0.0, abs=1e-9)


def test_readings_carry_every_count_and_dropouts_are_single() -> None:
    legs = square_legs(side=0.5)
    clean, faulty = synth_log(legs), synth_log(legs, dropout=0.2)
    assert len(clean) > 100 and np.all(np.diff(clean.stamp) > 0) and list(clean.seq[:3]) == [0, 1, 2]
    dropped = (faulty.left == 0) & (clean.left != 0)
    assert dropped.any() and not (dropped[1:] & dropped[:-1]).any()
    first = json.loads(clean.jsonl().splitlines()[0])
    message = clean.messages()[0]
    assert first == {"seq": message.seq, "stamp": message.stamp, "left": message.left, "right": message.right}
