"""The e-stop latch kept where the deployment keeps state, so a crash, a restart or a reboot is not a release.

An engage is saved right after its EMG_STOP bytes were written; a release takes effect only once saved, so a
restart can only come up engaged. A file that is missing, unreadable, corrupt or for another prefix, or a folder
that cannot be written, starts the gateway engaged with one sentence why. Writes are atomic.
"""

from __future__ import annotations

import os
import urllib.parse
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import msgspec

#: How the latch is named in health when it took its state at start and not from a key.
AT_START = "gateway start"


@dataclass(frozen=True, slots=True)
class Latch:
    """The e-stop's state, when it took it (Unix time) and what put it there (a key, or why it started engaged)."""

    engaged: bool
    since: float
    by: str


@dataclass(frozen=True, slots=True)
class Untrusted:
    """Why there is no saved latch to trust: one sentence, and whether the file is merely absent."""

    reason: str
    missing: bool = False


class _LatchFile(msgspec.Struct, forbid_unknown_fields=True):
    prefix: str
    engaged: bool
    since: float
    by: str


_decoder = msgspec.json.Decoder(_LatchFile)


class LatchStore(Protocol):
    """Where one robot's latch is kept."""

    @property
    def where(self) -> str: ...

    def load(self) -> Latch | Untrusted:
        """The saved latch, or why there is none to trust (missing, unreadable, corrupt)."""

    def save(self, latch: Latch) -> str | None:
        """Keep ``latch`` so that a restart finds it; None, or why it could not be kept."""


def default_state_dir() -> str:
    """systemd's ``$STATE_DIRECTORY`` (``StateDirectory=``), else ``$XDG_STATE_HOME/blackmetal``, else ``~/.local/state/blackmetal``."""
    systemd = os.environ.get("STATE_DIRECTORY")
    if systemd:
        return systemd.split(":")[0]
    xdg = os.environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local", "state")
    return os.path.join(xdg, "blackmetal")


def latch_path(state_dir: str, prefix: str) -> Path:
    """The latch file of ``prefix`` under ``state_dir`` (``fleet/r3`` -> ``estop/fleet%2Fr3.json``)."""
    return Path(os.path.expanduser(state_dir)) / "estop" / f"{urllib.parse.quote(prefix, safe='')}.json"


@dataclass
class FileLatchStore:
    """The latch of ``prefix`` in a JSON file, written atomically and synced."""

    path: Path
    prefix: str

    @property
    def where(self) -> str:
        return str(self.path)

    def load(self) -> Latch | Untrusted:
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            return Untrusted(f"no saved e-stop state at {self.path} (a first start, or the file was lost)", missing=True)
        except OSError as exc:
            return Untrusted(f"the saved e-stop state {self.path} cannot be read ({exc.strerror}): check its permissions")
        try:
            saved = _decoder.decode(data)
        except (msgspec.DecodeError, msgspec.ValidationError) as exc:
            return Untrusted(f"the saved e-stop state {self.path} is corrupt ({exc})")
        if saved.prefix != self.prefix:
            return Untrusted(f"the saved e-stop state {self.path} is for prefix {saved.prefix!r}, not {self.prefix!r}")
        return Latch(saved.engaged, saved.since, saved.by)

    def save(self, latch: Latch) -> str | None:
        content = msgspec.json.encode(_LatchFile(self.prefix, latch.engaged, latch.since, latch.by)) + b"\n"
        folder = self.path.parent
        temporary = folder / f".{self.path.name}.{os.getpid()}.new"
        try:
            folder.mkdir(parents=True, exist_ok=True)
            descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            try:
                os.write(descriptor, content)
                os.fsync(descriptor)
            finally:
                os.close(descriptor)
            os.replace(temporary, self.path)
            folder_descriptor = os.open(folder, os.O_RDONLY)
            try:
                os.fsync(folder_descriptor)
            finally:
                os.close(folder_descriptor)
        except OSError as exc:
            try:
                temporary.unlink(missing_ok=True)
            except OSError:
                pass
            return f"the e-stop state cannot be saved to {self.path} ({exc.strerror}): check that the folder is writable (--state-dir)"
        return None


def start_latch(store: LatchStore, wallclock: float, missing_released: bool = False) -> tuple[Latch, str | None]:
    """The latch a gateway starts with, and the sentence to say if it starts engaged for want of a trusted state;
    with ``missing_released`` a merely absent file starts released (a robot known to be new, as ``blackmetal up``'s)."""
    loaded = store.load()
    if isinstance(loaded, Latch):
        latch = loaded
    elif missing_released and loaded.missing:
        latch = Latch(False, wallclock, AT_START)
    else:
        engaged = Latch(True, wallclock, f"{AT_START}: {loaded.reason}")
        failure = store.save(engaged)
        why = loaded.reason if failure is None else f"{loaded.reason}; and {failure}"
        return engaged, f"the e-stop is engaged at start: {why}; release it with `blackmetal estop off` once the robot is safe"
    failure = store.save(latch)
    if failure is None:
        return latch, None
    if latch.engaged:
        return latch, f"the e-stop stays engaged, but {failure}"
    engaged = Latch(True, wallclock, f"{AT_START}: {failure}")
    return engaged, f"the e-stop is engaged at start: {failure}, so a release could not be kept"
