"""``up --settings FILE``: one file with any service's keys, split into each service's own settings file."""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
from pathlib import Path
from typing import Any

from blackmetal.foxglove.settings import FoxgloveSettings
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.nav.settings import NavSettings
from blackmetal.odometry_service.settings import OdometrySettings
from blackmetal.robot_model import RESIDUAL_LINE
from blackmetal.ros2.settings import Ros2Settings
from blackmetal.runtime.settings import load_settings, read_settings_file
from blackmetal.runtime.zenoh_setup import ZenohSettings
from blackmetal.schemas import ConfigError
from blackmetal.sim.settings import SimSettings

#: The services ``up --settings FILE`` can configure, by section name.
SERVICES: dict[str, type] = {
    "gateway": GatewaySettings,
    "odometry": OdometrySettings,
    "nav": NavSettings,
    "sim": SimSettings,
    "ros2": Ros2Settings,
    "foxglove": FoxgloveSettings,
}
#: Keys outside a section go to every one of these that has the setting. Not to the simulator: its wheel
#: settings are the true robot's, not a calibration's; a key only the simulator knows still goes to it.
SHARED = ("gateway", "odometry", "nav", "ros2", "foxglove")
#: What up decides itself, whatever a settings file says: the robot (simulator or --robot) and the Zenoh endpoints.
UP_DECIDES = frozenset({"robot", "control_port", "log_port"}) | {
    f.name for f in dataclasses.fields(ZenohSettings) if f.metadata.get("cli", True)
}


def _setting_names(cls: type) -> set[str]:
    return {f.name for f in dataclasses.fields(cls) if f.name != "zenoh"}


def split_settings(path: str) -> tuple[dict[str, dict[str, Any]], list[str]]:
    """Each service's own keys (top-level keys go to every SHARED service that has them, a ``[SERVICE]``
    section to that one), and the keys up decides itself; a key no service has is a ConfigError."""
    data = read_settings_file(path)
    own: dict[str, dict[str, Any]] = {name: {} for name in SERVICES}
    unknown: list[str] = []
    decided: list[str] = []

    def place(key: str, value: Any, names: tuple[str, ...], label: str) -> None:
        if key in UP_DECIDES:
            decided.append(label)
            return
        takers = [name for name in names if key in _setting_names(SERVICES[name])]
        if not takers and names == SHARED and key in _setting_names(SimSettings):
            takers = ["sim"]
        if not takers:
            unknown.append(label)
        for name in takers:
            own[name][key] = value

    for key, value in data.items():
        if key in SERVICES and isinstance(value, dict):
            for sub, sub_value in value.items():
                sub = str(sub).replace("-", "_")
                place(sub, sub_value, (key,), f"{key}.{sub}")
        else:
            place(key, value, SHARED, key)
    if unknown:
        raise ConfigError(
            f"settings file {path}: unknown settings {sorted(unknown)}: no service ({', '.join(SERVICES)}) has them; "
            "`blackmetal SERVICE --help` lists each one's, and a [SERVICE] section gives a key to one service only"
        )
    return own, decided


class ServiceFiles:
    """Each service's part of ``up --settings FILE``, written as its own JSON file for its ``--settings``."""

    def __init__(self, path: str | None, services: list[str]) -> None:
        self._dir: tempfile.TemporaryDirectory[str] | None = None
        self.files: dict[str, str] = {}
        #: Each service's own keys from the file (empty without a file).
        self.own: dict[str, dict[str, Any]] = {}
        self.prefix: str | None = None
        self.decided: list[str] = []
        if not path:
            return
        own, self.decided = split_settings(path)
        self.own = own
        prefixes = {str(values["prefix"]) for values in own.values() if "prefix" in values}
        if len(prefixes) > 1:
            raise ConfigError(f"settings file {path}: one demo has one prefix, got {sorted(prefixes)}")
        self.prefix = prefixes.pop() if prefixes else None
        self._dir = tempfile.TemporaryDirectory(prefix="blackmetal-up-")
        for name in services:
            if not own[name]:
                continue
            file = Path(self._dir.name) / f"{name}.json"
            file.write_text(json.dumps(own[name], default=str))
            load_settings(SERVICES[name], {}, settings_file=str(file))  # a bad value: one sentence now, not a failed child
            self.files[name] = str(file)

    def args(self, name: str) -> list[str]:
        return ["--settings", self.files[name]] if name in self.files else []

    def sets(self, name: str, key: str) -> bool:
        """Whether the file gives service ``name`` the setting ``key`` (up then leaves it to the file)."""
        return key in self.own.get(name, {})

    def run_dir(self) -> str:
        """This run's folder (removed when up ends): the state of its simulated robots."""
        if self._dir is None:
            self._dir = tempfile.TemporaryDirectory(prefix="blackmetal-up-")
        return self._dir.name

    def close(self) -> None:
        if self._dir is not None:
            self._dir.cleanup()


def ros2_extra(args: argparse.Namespace) -> list[str]:
    """``--distro``, and ``--calibration FILE`` for a calibration with residuals (comments, which the split drops)."""
    extra = ["--distro", args.distro] if args.distro else []
    if args.settings and Path(args.settings).suffix == ".toml":
        try:
            text = Path(args.settings).read_text()
        except OSError:
            return extra  # ServiceFiles has said what is wrong with it
        if any(line.startswith(RESIDUAL_LINE) for line in text.splitlines()):
            extra += ["--calibration", str(args.settings)]
    return extra


def latch_args(args: argparse.Namespace, files: ServiceFiles) -> list[str]:
    """Simulated robots latch in this run's folder, released at first (they are new); a real robot (``--robot``)
    keeps the gateway's default, so a latch engaged before a crash, a restart or a reboot stays engaged."""
    if args.robot:
        return []
    return ["--state-dir", files.run_dir(), "--unsafe-start-released"]
