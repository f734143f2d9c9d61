"""The odometry's errors (:mod:`blackmetal.odometry_service.errors`): what catches what.

The core reports every :class:`SampleRejected` on ``<prefix>/errors`` and
goes on; the commands turn any :class:`BlackmetalError` into one sentence.
So an unstamped sample must be a rejected sample (reported, never a crash),
and every odometry error must be a BlackmetalError. The drawing of the whole
tree is tests/unit/schemas/test_errors.py's.
"""

from __future__ import annotations

import pytest

from blackmetal.odometry_service.calibration import CalibrationError
from blackmetal.odometry_service.errors import OdometryError, ReplayError, SampleRejected, UnstampedSample
from blackmetal.odometry_service.integrator import Odometry
from blackmetal.schemas import BlackmetalError, WheelImpulses


def test_a_live_sample_without_its_stamps_is_rejected_as_any_unusable_sample_is() -> None:
    odometry = Odometry(live=True)
    with pytest.raises(SampleRejected) as rejected:
        odometry.feed(WheelImpulses(seq=0, stamp=1.0, left=0, right=0), arrival=1.0)
    assert type(rejected.value) is UnstampedSample and "impulses without mono and source" in str(rejected.value)


@pytest.mark.parametrize("error", [SampleRejected, UnstampedSample, ReplayError, CalibrationError])
def test_every_odometry_error_ends_in_the_one_sentence_of_the_commands(error: type[Exception]) -> None:
    assert issubclass(error, OdometryError) and issubclass(error, BlackmetalError)
    assert not issubclass(error, (ValueError, RuntimeError))  # a bug of ours is not mistaken for a bad input


def test_a_replay_or_calibration_error_is_no_rejected_sample() -> None:
    """The core reports rejected samples and goes on; a replay that cannot be read must stop, not be skipped."""
    assert not issubclass(ReplayError, SampleRejected) and not issubclass(CalibrationError, SampleRejected)
