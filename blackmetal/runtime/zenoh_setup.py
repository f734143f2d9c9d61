"""The Zenoh flags every blackmetal process shares, as zenoh-python's examples spell them.

``-m/--mode``, ``-e/--connect``, ``-l/--listen``, ``-c/--config``,
``--multicast-scouting`` / ``--no-multicast-scouting``. Importing zenoh is
deferred so that a process that does not use Zenoh (the plain simulator)
never loads it.

Isolated by default, like ROS 2's own Zenoh middleware: a blackmetal
process finds only the endpoints it is given. Multicast scouting and gossip
(peers telling each other about third peers, which links two robots'
sessions for good once any peer has met both) are off unless
``--multicast-scouting`` asks for discovery on the LAN; a Zenoh config file
given with ``-c`` decides for itself. Without gossip, a session that listens
is a hub that routes for the sessions connected to it as clients, so a
process given ``-e`` and no ``-l`` (and no ``-m``) connects as a client of
exactly that endpoint.
"""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from schemas import ConfigError, ZenohUnavailable

if TYPE_CHECKING:
    import zenoh

MODES = ("peer", "client", "router")


def _env(name: str) -> str | None:
    return os.environ.get(name) or None


@dataclass(slots=True)
class ZenohSettings:
    """What the shared flags say; turned into a ``zenoh.Config`` by :meth:`to_config`."""

    mode: str | None = None
    connect: list[str] = field(default_factory=list)
    listen: list[str] = field(default_factory=list)
    config: str | None = None
    #: Discover peers on the LAN by multicast (and let peers gossip about others). Off by default.
    multicast_scouting: bool = False
    #: Accepted for scripts written before isolation became the default; off is the default anyway.
    no_multicast_scouting: bool = False
    #: Zenoh user/password authentication, from the environment only
    #: (BLACKMETAL_ZENOH_USER / BLACKMETAL_ZENOH_PASSWORD) so no secret sits on a command line or in a file.
    user: str | None = field(default_factory=lambda: _env("BLACKMETAL_ZENOH_USER"), metadata={"cli": False})
    password: str | None = field(default_factory=lambda: _env("BLACKMETAL_ZENOH_PASSWORD"), metadata={"cli": False})

    def __post_init__(self) -> None:
        if self.mode is not None and self.mode not in MODES:
            raise ConfigError(f"Zenoh mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        for endpoint in [*self.connect, *self.listen]:
            check_endpoint(endpoint)

    @property
    def given(self) -> bool:
        """True when any Zenoh flag was set."""
        return bool(self.mode or self.connect or self.listen or self.config or self.no_multicast_scouting or self.multicast_scouting)

    def where(self) -> str:
        """Where this session looks for others, for messages."""
        if self.connect:
            return ", ".join(self.connect)
        return "multicast scouting" if self.discovers else "no endpoint"

    @property
    def discovers(self) -> bool:
        """Whether this session looks for peers by multicast and gossip."""
        return self.multicast_scouting and not self.no_multicast_scouting

    def to_config(self) -> "zenoh.Config":
        import zenoh

        if self.config is not None:
            path = Path(self.config)
            if not path.is_file():
                raise ConfigError(f"Zenoh config file {path} does not exist")
            try:
                conf = zenoh.Config.from_file(str(path))
            except Exception as exc:  # zenoh raises its own ZError with the parser's text
                raise ConfigError(f"Zenoh config file {path} is invalid: {exc}") from None
        else:
            conf = zenoh.Config()
        try:
            mode = self.mode
            if mode is None and self.config is None and self.connect and not self.listen and not self.discovers:
                mode = "client"  # isolated: talk to exactly the endpoint given, through it to the rest
            if mode is not None:
                conf.insert_json5("mode", json.dumps(mode))
            if self.connect:
                conf.insert_json5("connect/endpoints", json.dumps(self.connect))
            if self.listen:
                conf.insert_json5("listen/endpoints", json.dumps(self.listen))
            if self.config is None or self.multicast_scouting or self.no_multicast_scouting:
                discover = json.dumps(self.discovers)
                conf.insert_json5("scouting/multicast/enabled", discover)
                conf.insert_json5("scouting/gossip/enabled", discover)
            if self.user is not None:
                if self.password is None:
                    raise ConfigError("BLACKMETAL_ZENOH_USER is set but BLACKMETAL_ZENOH_PASSWORD is not")
                conf.insert_json5("transport/auth/usrpwd/user", json.dumps(self.user))
                conf.insert_json5("transport/auth/usrpwd/password", json.dumps(self.password))
        except ConfigError:
            raise
        except Exception as exc:
            raise ConfigError(f"invalid Zenoh setting: {exc}") from None
        return conf


def check_endpoint(endpoint: str) -> str:
    """``tcp/HOST:PORT`` (or another Zenoh protocol); ConfigError with an example otherwise."""
    protocol, slash, address = endpoint.partition("/")
    if not slash or not protocol or not address or ":" not in address:
        raise ConfigError(f"endpoint {endpoint!r} must look like PROTOCOL/HOST:PORT, for example tcp/127.0.0.1:7447 or tcp/[::1]:7447")
    return endpoint


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the shared Zenoh flags to ``parser`` (unset flags stay None, so settings files can fill them)."""
    group = parser.add_argument_group("Zenoh")
    group.add_argument("-m", "--mode", choices=MODES, default=None, help="Zenoh session mode (default: peer)")
    group.add_argument(
        "-e",
        "--connect",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    group.add_argument("-l", "--listen", action="append", default=None, metavar="ENDPOINT", help="endpoint to listen on (repeatable)")
    group.add_argument("-c", "--config", default=None, metavar="FILE", help="Zenoh configuration file (JSON5)")
    group.add_argument(
        "--multicast-scouting",
        action="store_const",
        const=True,
        default=None,
        help="discover peers on the LAN by multicast and gossip (default: off, only the endpoints given)",
    )
    group.add_argument(
        "--no-multicast-scouting",
        action="store_const",
        const=True,
        default=None,
        help="no discovery (the default; accepted for older scripts)",
    )


def zenoh_settings(args: argparse.Namespace | Any) -> ZenohSettings:
    """ZenohSettings from parsed arguments that carry the shared flags."""
    return ZenohSettings(
        mode=getattr(args, "mode", None),
        connect=list(getattr(args, "connect", None) or []),
        listen=list(getattr(args, "listen", None) or []),
        config=getattr(args, "config", None),
        no_multicast_scouting=bool(getattr(args, "no_multicast_scouting", False)),
        multicast_scouting=bool(getattr(args, "multicast_scouting", False)),
    )


def open_session(settings: ZenohSettings) -> "zenoh.Session":
    """Open a session; ZenohUnavailable with what to check instead of Zenoh's own traceback."""
    import zenoh

    conf = settings.to_config()
    try:
        return zenoh.open(conf)
    except Exception as exc:  # zenoh.ZError carries the reason as text
        raise ZenohUnavailable(unavailable_reason(settings, str(exc))) from None


def unavailable_reason(settings: ZenohSettings, text: str) -> str:
    """One sentence from Zenoh's error text: what failed and what to check."""
    if "Address already in use" in text:
        return (
            f"cannot listen on {', '.join(settings.listen)}: the port is in use by another process "
            "(another `blackmetal up`, a router or a service?); stop it, or choose another port with -l tcp/127.0.0.1:PORT"
        )
    if "Unable to connect" in text:
        credentials = (
            "that BLACKMETAL_ZENOH_USER and BLACKMETAL_ZENOH_PASSWORD are right for it"
            if settings.user is not None
            else "whether it asks for a user and password (set BLACKMETAL_ZENOH_USER and BLACKMETAL_ZENOH_PASSWORD)"
        )
        return (
            f"cannot reach {', '.join(settings.connect)}: check that a router or `blackmetal up` runs there, "
            f"that the address and port are right (-e tcp/HOST:PORT), and {credentials}"
        )
    if "lookup address" in text:
        return f"cannot resolve an address in {', '.join(settings.connect + settings.listen)}: check the host name"
    return f"cannot open a Zenoh session ({settings.where()}): {text.split(' at /')[0]}"
