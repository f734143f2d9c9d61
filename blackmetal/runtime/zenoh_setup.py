"""The Zenoh flags every blackmetal process shares (``-m -e -l -c --multicast-scouting``) and opening its session.

Isolated by default (docs/concepts.md, "Isolated by default"). A service waits for its router and rides out its
restarts (docs/deploying.md, "Start order"); ``zenoh.open`` then blocks, so it runs on a daemon thread. The user tools
use :func:`open_session`, which fails at once with one sentence. zenoh is imported late: the plain simulator never
loads it.
"""

from __future__ import annotations

import argparse
import asyncio
import ipaddress
import json
import os
import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from blackmetal.schemas import ConfigError, ZenohUnavailable, ZenohUnreachable

if TYPE_CHECKING:
    import zenoh

MODES = ("peer", "client", "router")
#: Where every process connects when told nothing else: the hub of ``blackmetal up`` and ``blackmetal router``.
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
#: Zenoh's connect retry for services (Zenoh's default, 1 s doubling to 4 s, is too slow to join a router within 2 s of
#: it coming up). It also paces reconnecting after the router restarts.
SERVICE_RETRY = "{period_init_ms: 100, period_max_ms: 500, period_increase_factor: 2}"
#: How long a service tries quietly before it says that it waits.
WAIT_NOTICE_S = 0.5


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
    #: Zenoh user/password authentication, from the environment only (BLACKMETAL_ZENOH_USER / BLACKMETAL_ZENOH_PASSWORD)
    #: so no secret sits on a command line or in a file.
    user: str | None = field(default_factory=lambda: os.environ.get("BLACKMETAL_ZENOH_USER") or None, metadata={"cli": False})
    password: str | None = field(default_factory=lambda: os.environ.get("BLACKMETAL_ZENOH_PASSWORD") or None, metadata={"cli": False})

    def __post_init__(self) -> None:
        if self.mode is not None and self.mode not in MODES:
            raise ConfigError(f"Zenoh mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        for endpoint in [*self.connect, *self.listen]:
            check_endpoint(endpoint)

    @property
    def given(self) -> bool:
        return bool(self.mode or self.connect or self.listen or self.config or self.no_multicast_scouting or self.multicast_scouting)

    @property
    def defaulted(self) -> bool:
        """No endpoint, config file or discovery given: the session is a client of :data:`DEFAULT_ENDPOINT`."""
        return not (self.connect or self.listen or self.config is not None or self.discovers) and self.mode != "router"

    @property
    def endpoints(self) -> list[str]:
        """The endpoints this session connects to: those given, or the default one."""
        return [DEFAULT_ENDPOINT] if self.defaulted else list(self.connect)

    @property
    def is_hub(self) -> bool:
        """A session that listens (or a router): others join it; it does not wait for anyone."""
        return bool(self.listen) or self.mode == "router"

    def where(self) -> str:
        """Where this session looks for others, for messages."""
        if self.endpoints:
            return ", ".join(self.endpoints)
        if self.listen:
            return "listening on " + ", ".join(self.listen)
        if self.discovers:
            return "multicast scouting"
        return f"as {self.config} says" if self.config is not None else "no endpoint"

    @property
    def discovers(self) -> bool:
        """Whether this session looks for peers by multicast and gossip."""
        return self.multicast_scouting and not self.no_multicast_scouting

    def to_config(self, wait: bool = False) -> "zenoh.Config":
        """The Zenoh config; with ``wait``, a session that waits for its endpoints and rejoins them (services), unless a
        config file sets ``connect/timeout_ms`` itself."""
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
            connect = self.endpoints
            if mode is None and self.config is None and connect and not self.listen and not self.discovers:
                mode = "client"  # isolated: talk to exactly the endpoint given, through it to the rest
            if mode is not None:
                conf.insert_json5("mode", json.dumps(mode))
            if connect:
                conf.insert_json5("connect/endpoints", json.dumps(connect))
            if wait and not _file_sets_connect_timeout(self.config):
                conf.insert_json5("connect/timeout_ms", "-1")  # wait for the endpoints for ever...
                conf.insert_json5("connect/exit_on_failure", "false")  # ...never give up on them...
                conf.insert_json5("connect/retry", SERVICE_RETRY)  # ...and try every 0.1-0.5 s
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


def _file_sets_connect_timeout(path: str | None) -> bool:
    """Whether the Zenoh config file at ``path`` chooses its own ``connect/timeout_ms``."""
    if path is None:
        return False
    import json5

    try:
        data = json5.loads(Path(path).read_text())
    except (OSError, ValueError):
        return False  # zenoh has read it already; a file it accepts but json5 does not keeps our settings
    connect = data.get("connect") if isinstance(data, dict) else None
    return isinstance(connect, dict) and "timeout_ms" in connect


def check_endpoint(endpoint: str) -> str:
    """``tcp/HOST:PORT`` (or another Zenoh protocol); ConfigError with an example otherwise, or naming a port out of range."""
    protocol, slash, address = endpoint.partition("/")
    if not slash or not protocol or not address or ":" not in address:
        raise ConfigError(f"endpoint {endpoint!r} must look like PROTOCOL/HOST:PORT, for example tcp/127.0.0.1:7447 or tcp/[::1]:7447")
    port = address.split("#", 1)[0].split("?", 1)[0].rpartition(":")[2]
    if protocol in ("tcp", "udp", "tls", "quic", "ws") and not (port.isdigit() and 0 <= int(port) <= 65535):
        raise ConfigError(f"endpoint {endpoint!r} has an invalid port {port!r}: a port is a number from 1 to 65535")
    return endpoint


def unresolvable(endpoints: list[str]) -> list[str]:
    """The host names of ``endpoints`` that do not resolve now (IP addresses never asked): said while a service waits."""
    names = []
    for endpoint in endpoints:
        host = endpoint.partition("/")[2].split("#", 1)[0].rpartition(":")[0].strip("[]")
        try:
            ipaddress.ip_address(host)
            continue
        except ValueError:
            pass
        try:
            socket.getaddrinfo(host, None)
        except (socket.gaierror, UnicodeError):
            names.append(host)
    return names


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the shared Zenoh flags to ``parser`` (unset flags stay None, so settings files can fill them)."""
    group = parser.add_argument_group("Zenoh")
    endpoints: dict[str, Any] = {"action": "append", "metavar": "ENDPOINT"}
    switch: dict[str, Any] = {"action": "store_const", "const": True}
    group.add_argument(
        "-m", "--mode", choices=MODES, default=None, help="Zenoh session mode (default: client with -e and no -l, else peer)"
    )
    connect_help = f"endpoint to connect to (repeatable; default {DEFAULT_ENDPOINT} unless -l, -c or --multicast-scouting)"
    group.add_argument("-e", "--connect", default=None, help=connect_help, **endpoints)
    group.add_argument("-l", "--listen", default=None, help="endpoint to listen on, as a hub (repeatable)", **endpoints)
    group.add_argument("-c", "--config", default=None, metavar="FILE", help="Zenoh configuration file (JSON5)")
    scouting_help = "discover peers on the LAN by multicast and gossip (default: off, only the endpoints given)"
    group.add_argument("--multicast-scouting", default=None, help=scouting_help, **switch)
    group.add_argument("--no-multicast-scouting", default=None, help="no discovery (the default; accepted for older scripts)", **switch)


def zenoh_settings(args: argparse.Namespace | Any) -> ZenohSettings:
    return ZenohSettings(
        mode=getattr(args, "mode", None),
        connect=list(getattr(args, "connect", None) or []),
        listen=list(getattr(args, "listen", None) or []),
        config=getattr(args, "config", None),
        no_multicast_scouting=bool(getattr(args, "no_multicast_scouting", False)),
        multicast_scouting=bool(getattr(args, "multicast_scouting", False)),
    )


def open_session(settings: ZenohSettings) -> "zenoh.Session":
    """Open a session at once (the user tools); ZenohUnavailable with what to check instead of Zenoh's own traceback."""
    import zenoh

    conf = settings.to_config()
    try:
        return zenoh.open(conf)
    except Exception as exc:  # zenoh.ZError carries the reason as text
        raise unavailable_error(settings, str(exc)) from None


class PendingSession:
    """``zenoh.open`` of a service's config on a daemon thread, and whether the session has joined its endpoints.

    A client's ``zenoh.open`` blocks until its router answers and cannot be interrupted, so it runs here while the
    caller watches its stop request; a session opened after the caller gave up is closed. :meth:`step` says once what it
    waits for, and where the session is once it is ready.
    """

    def __init__(self, settings: ZenohSettings, name: str) -> None:
        self.settings = settings
        self.name = name
        self._conf = settings.to_config(wait=True)
        self._lock = threading.Lock()
        self._done = threading.Event()
        self._session: zenoh.Session | None = None
        self._error: str | None = None
        self._abandoned = False
        self._started = time.monotonic()
        self._waited = False
        threading.Thread(target=self._open, name="zenoh-open", daemon=True).start()

    def _open(self) -> None:
        import zenoh

        try:
            session = zenoh.open(self._conf)
        except Exception as exc:  # zenoh.ZError carries the reason as text
            self._error = str(exc)
            self._done.set()
            return
        with self._lock:
            if self._abandoned:
                session.close()
                return
            self._session = session
        self._done.set()

    def _conf_value(self, path: str) -> Any:
        try:
            return json.loads(self._conf.get_json(path))
        except Exception:
            return None

    @property
    def endpoints(self) -> list[str]:
        """What it connects to, for people: the flags' endpoints, or the config file's."""
        if self.settings.endpoints:
            return self.settings.endpoints
        found = self._conf_value("connect/endpoints")
        return [str(e) for e in found] if isinstance(found, list) else []

    def ready(self) -> "zenoh.Session | None":
        """The session once it is open and (unless it is a hub) connected; ZenohUnavailable if it cannot open."""
        if not self._done.is_set():
            return None
        if self._error is not None:
            raise unavailable_error(self.settings, self._error)
        session = self._session
        assert session is not None
        if self.is_hub or not self.endpoints:
            return session
        info = session.info
        return session if list(info.routers_zid()) or list(info.peers_zid()) else None

    def step(self) -> "zenoh.Session | None":
        """:meth:`ready`, saying where the session is once it is, and once what it waits for."""
        session = self.ready()
        if session is not None:
            self._say(self.status())
        elif not self._waited and time.monotonic() - self._started >= WAIT_NOTICE_S:
            self._waited = True
            self._say(f"waiting for {', '.join(self.endpoints)} (router or hub); starting when it answers (Ctrl-C to stop)")
            for host in unresolvable(self.endpoints):
                self._say(f"the host name {host!r} does not resolve: check the name in -e (waiting on, in case it comes up)")
        return session

    def _say(self, line: str) -> None:
        print(f"blackmetal {self.name}: {line}", flush=True)

    def abandon(self) -> None:
        """The caller stops waiting: close the session now or when it opens."""
        with self._lock:
            self._abandoned = True
            session, self._session = self._session, None
        if session is not None:
            session.close()

    @property
    def is_hub(self) -> bool:
        """It listens (or routes): it serves at once and connects to its endpoints in the background."""
        return self.settings.is_hub or self._conf_value("mode") == "router"

    def status(self) -> str:
        """One line for people: where the open session is."""
        where = ", ".join(self.endpoints)
        if self.is_hub:
            listen = ", ".join(self.settings.listen) or "the endpoints of its config"
            return f"listening on {listen} (a hub)" + (f", connecting to {where}" if where else "")
        return f"connected to {where}" if where else f"Zenoh {self.settings.where()}"


async def open_service_session(settings: ZenohSettings, stop: asyncio.Event, name: str, poll: float = 0.02) -> "zenoh.Session":
    """A service's session, once it has joined its router or hub (a hub: at once); says once what it waits for.

    ``stop`` set first: asyncio.CancelledError (``run_service`` exits 0); ZenohUnavailable when the session cannot open
    at all (a port in use, a bad config).
    """
    pending, session = PendingSession(settings, name), None
    try:
        while (session := pending.step()) is None:
            try:
                await asyncio.wait_for(stop.wait(), timeout=poll)
            except TimeoutError:
                continue
            raise asyncio.CancelledError(f"{name} stopped while it waited for its router or hub")
    finally:
        if session is None:
            pending.abandon()
    return session


def open_when_reachable(settings: ZenohSettings, stop: threading.Event, name: str, poll: float = 0.02) -> "zenoh.Session | None":
    """:func:`open_service_session` for a thread-based process (the recorder, ``up``); None when ``stop`` came first."""
    pending, session = PendingSession(settings, name), None
    try:
        while (session := pending.step()) is None and not stop.wait(poll):
            continue
    finally:
        if session is None:
            pending.abandon()
    return session


def unavailable_error(settings: ZenohSettings, text: str) -> ZenohUnavailable:
    """The error for Zenoh's failure text: :class:`ZenohUnreachable` when nothing answered, which a caller may retry."""
    reason = unavailable_reason(settings, text)
    return ZenohUnreachable(reason) if "Unable to connect" in text else ZenohUnavailable(reason)


def unavailable_reason(settings: ZenohSettings, text: str) -> str:
    """One sentence from Zenoh's error text: what failed and what to check."""
    if "Address already in use" in text:
        return (
            f"cannot listen on {', '.join(settings.listen)}: the port is in use by another process "
            "(another `blackmetal up`, a router or a service?); stop it, or choose another port with -l tcp/127.0.0.1:PORT"
        )
    if "Unable to connect" in text:
        endpoints = ", ".join(settings.endpoints) or "the config's endpoints"
        credentials = (
            "that BLACKMETAL_ZENOH_USER and BLACKMETAL_ZENOH_PASSWORD are right for it"
            if settings.user is not None
            else "whether it asks for a user and password (set BLACKMETAL_ZENOH_USER and BLACKMETAL_ZENOH_PASSWORD)"
        )
        return (
            f"cannot reach {endpoints}: check that a router or `blackmetal up` runs there, "
            f"that the address and port are right (-e tcp/HOST:PORT), and {credentials}"
        )
    if "lookup address" in text:
        return f"cannot resolve an address in {', '.join(settings.endpoints + settings.listen)}: check the host name"
    return f"cannot open a Zenoh session ({settings.where()}): {text.split(' at /')[0]}"
