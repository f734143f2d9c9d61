"""The one error hierarchy of blackmetal, rooted here at the bottom layer so every package can use it.

Every error a blackmetal module raises on purpose derives from
:class:`BlackmetalError`; a command catches that root and prints one
sentence instead of a traceback. The whole tree, each class with the module
that defines it (``tests/unit/schemas/test_errors.py`` checks the drawing against the
classes, so a new class, a new parent or a moved module is drawn here)::

    BlackmetalError                      blackmetal.schemas.errors
    ├── ConfigError                      blackmetal.schemas.errors: a setting, flag, prefix or Zenoh config is unusable
    │   └── MissingExtra                 blackmetal.schemas.errors: an optional extra (ros2, record, foxglove) is not installed
    ├── ZenohUnavailable                 blackmetal.schemas.errors: no Zenoh session (router down, port in use, credentials)
    │   └── ZenohUnreachable             blackmetal.schemas.errors: nothing answers at the endpoints (yet: a router may still be starting)
    ├── PayloadError (also ValueError)   blackmetal.schemas.errors: bytes on a key are not a valid message
    ├── ProtocolError                    blackmetal.wire: a command the robot must never see, or a bad wire value
    ├── ChildFailed                      blackmetal.runtime.harness: a child process exited or was not ready in time; its last lines
    ├── ServiceFailure                   blackmetal.foxglove.sdk:  a Foxglove service call that could not be done; its text goes to the caller
    ├── OdometryError                    blackmetal.odometry_service.errors
    │   ├── SampleRejected               blackmetal.odometry_service.errors: an impulse sample that cannot be integrated
    │   │   └── UnstampedSample          blackmetal.odometry_service.errors: a live sample without ``mono`` or ``source``
    │   ├── ReplayError                  blackmetal.odometry_service.errors: a recording that cannot be replayed; names the line
    │   └── CalibrationError             blackmetal.odometry_service.calibration: recordings that cannot calibrate anything
    └── ToolError                        blackmetal.tools.client: a user tool cannot do its job; says what to check
        └── Cancelled                    blackmetal.tools.square: the square was stopped (Ctrl-C); the robot is stopped
"""

from __future__ import annotations


class BlackmetalError(Exception):
    """Root of every error blackmetal raises on purpose; see the module docstring for the tree."""


class ConfigError(BlackmetalError):
    """A setting is missing, malformed or out of range; the text names it and says what would work."""


class MissingExtra(ConfigError):
    """A command needs an optional extra that is not installed; the text says what to ``pip install``."""

    def __init__(self, command: str, extra: str, module: str) -> None:
        self.extra = extra
        super().__init__(f"{command} needs the {extra!r} extra (module {module!r} is missing): pip install 'blackmetal[{extra}]'")


def require_extra(command: str, extra: str, module: str) -> None:
    """MissingExtra unless ``module`` can be imported."""
    import importlib

    try:
        importlib.import_module(module)
    except ImportError:
        raise MissingExtra(command, extra, module) from None


class ZenohUnavailable(BlackmetalError):
    """A Zenoh session cannot be opened; the text says what to check (router address, port in use, credentials)."""


class ZenohUnreachable(ZenohUnavailable):
    """Nothing answers at the endpoints: unlike a port in use or a bad address, this may pass (a router still starting)."""


class PayloadError(BlackmetalError, ValueError):
    """A payload is not a valid message: the text says what was wrong, for a person; the message type's name and a
    short, printable excerpt of the payload let an error report say *what* was rejected."""

    def __init__(self, message_type: str, reason: str, excerpt: str = "") -> None:
        self.message_type = message_type
        self.reason = reason
        self.excerpt = excerpt
        super().__init__(f"invalid {message_type}: {reason}")
