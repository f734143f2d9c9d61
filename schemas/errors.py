"""The one error type of the schemas package."""

from __future__ import annotations


class SchemaError(ValueError):
    """Base of every error raised by :mod:`schemas`."""


class PayloadError(SchemaError):
    """A payload is not a valid message: the text says what was wrong, for a person.

    Carries the message type's name and a short, printable excerpt of the
    payload so that an error report can say *what* was rejected.
    """

    def __init__(self, message_type: str, reason: str, excerpt: str = "") -> None:
        self.message_type = message_type
        self.reason = reason
        self.excerpt = excerpt
        super().__init__(f"invalid {message_type}: {reason}")
