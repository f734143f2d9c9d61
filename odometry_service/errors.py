"""Errors of the odometry service, under the one root :class:`blackmetal.schemas.BlackmetalError`."""

from __future__ import annotations

from blackmetal.schemas import BlackmetalError


class OdometryError(BlackmetalError):
    """Base of the odometry service's errors."""


class SampleRejected(OdometryError):
    """An impulse sample that cannot be used (duplicate, out of order, stamp going backwards)."""


class UnstampedSample(SampleRejected):
    """A live impulse sample without ``mono`` or ``source``: no interval, arrival or one-gateway check could hold it."""


class ReplayError(OdometryError):
    """A recording that cannot be replayed; the text names the line."""
