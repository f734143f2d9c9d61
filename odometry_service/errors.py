"""The one error hierarchy of the odometry service."""

from __future__ import annotations


class OdometryError(Exception):
    """Base of every error raised by :mod:`odometry_service`."""


class SampleRejected(OdometryError):
    """An impulse sample that cannot be used (duplicate, out of order, stamp going backwards)."""


class ReplayError(OdometryError):
    """A replay file that cannot be read; the text names the line."""
