"""The one error hierarchy of the gateway package (which also holds the simulator)."""

from __future__ import annotations


class GatewayError(Exception):
    """Base of every error raised by :mod:`gateway`."""


class ProtocolError(GatewayError):
    """A command cannot be encoded, or bytes are not a valid robot message."""


class LinkError(GatewayError):
    """The TCP link to the robot failed: refused, closed, or silent too long."""


class ConfigError(GatewayError):
    """A setting is missing, malformed or out of range; the text says which."""
