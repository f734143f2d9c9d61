"""A fleet file: the robots one host serves, each with its link, its prefix and its own constants.

The format is in docs/fleets.md ("The fleet file"). Every process of a fleet reads the same file and takes what is its
own; a mistake ends in one sentence that names the robot.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import msgspec

from blackmetal.schemas import ConfigError, validate_prefix

from .settings import plain_words, read_config

T = TypeVar("T")

#: What every robot entry may say besides its service tables.
LINK_KEYS = ("id", "host", "control_port", "log_port", "prefix")
#: The robot's constants: the gateway and the odometry both take them, so they are written once.
CALIBRATION_KEYS = ("wheel_separation", "impulses_left", "impulses_right")
#: Per-service tables a robot entry may hold.
SERVICES = ("gateway", "odometry", "sim", "ros2", "foxglove", "nav")
#: Prefixes of a fleet's robots unless an entry names its own.
FLEET_ROOT = "fleet"
#: Robots one fleet file may hold, unless it says ``max_robots = N``: a fleet process carries about 140 robots a core at
#: 50 Hz (the bench: 0.72 gateway cores at 100 robots), so a file beyond this is a mistake, not a fleet.
MAX_ROBOTS = 250
#: A robot id: one key chunk a person can read and type, and a ROS namespace's part.
ID_PATTERN = re.compile(r"[A-Za-z0-9_-]{1,64}")


@dataclass(frozen=True, slots=True)
class FleetRobot:
    """One robot of the fleet file."""

    index: int  # 1-based, as a person counts the entries
    id: str
    host: str
    control_port: int
    log_port: int
    prefix: str
    calibration: dict[str, float] = field(default_factory=dict)
    tables: dict[str, dict[str, Any]] = field(default_factory=dict)

    def describe(self) -> str:
        return f"robot {self.index} (id {self.id!r})"

    def settings(self, service: str, base: T, link: dict[str, Any] | None = None) -> T:
        """``base`` (a settings dataclass) for this robot: its ``link`` fields, the calibration keys ``base``
        has, then its ``[robot.<service>]`` table; ConfigError naming the robot for an unknown or ill-typed key."""
        names = {f.name for f in dataclasses.fields(base)}  # type: ignore[arg-type]
        table = self.tables.get(service, {})
        unknown = sorted(set(table) - names - {"zenoh"})
        if unknown:
            known = ", ".join(sorted(names - {"zenoh"}))
            raise ConfigError(f"{self.describe()}: unknown {service} setting {unknown[0]!r} in [robot.{service}]; known: {known}")
        values = {**(link or {}), **{k: v for k, v in self.calibration.items() if k in names}, **table}
        try:
            typed = msgspec.convert(values, type(base), strict=False)  # every settings field has a default
        except msgspec.ValidationError as exc:
            where = dict.fromkeys(values, f"[robot.{service}]")
            raise ConfigError(f"{self.describe()}: {plain_words(str(exc), values, where)}") from None
        merged = dataclasses.replace(base, **{k: getattr(typed, k) for k in values})  # type: ignore[type-var]
        check = getattr(merged, "check", None)
        if callable(check):
            try:
                check()
            except ConfigError as exc:
                raise ConfigError(f"{self.describe()}: {exc}") from None
        return merged


def _need(entry: dict[str, Any], where: str, key: str, kind: type, default: Any = None) -> Any:
    value = entry.get(key, default)
    if value is None:
        raise ConfigError(f"{where}: {key} is missing")
    if isinstance(value, bool) or not isinstance(value, kind):
        raise ConfigError(f"{where}: {key} must be {'an integer' if kind is int else 'a string'}, got {value!r}")
    return value


def parse_fleet(data: dict[str, Any], source: str = "fleet file") -> list[FleetRobot]:
    """The robots of a parsed fleet file; ConfigError with one sentence naming the entry on any mistake."""
    extra = sorted(set(data) - {"robot", "max_robots"})
    if extra:
        raise ConfigError(f"{source}: unknown top-level key {extra[0]!r}; a fleet file holds max_robots and [[robot]] tables only")
    entries = data.get("robot")
    if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
        raise ConfigError(f"{source}: no [[robot]] tables; each robot is one [[robot]] with id, host, control_port, log_port")
    cap = data.get("max_robots", MAX_ROBOTS)
    if isinstance(cap, bool) or not isinstance(cap, int) or not 1 <= cap <= 10_000:
        raise ConfigError(f"{source}: max_robots must be an integer from 1 to 10000, got {cap!r}")
    if len(entries) > cap:
        raise ConfigError(
            f"{source}: {len(entries)} robots, more than the {cap} one process serves (about 140 a core at 50 Hz); "
            "split the fleet over several files and processes, or raise max_robots = N at the top of the file"
        )
    robots: list[FleetRobot] = []
    seen: dict[tuple[str, Any], FleetRobot] = {}
    for index, entry in enumerate(entries, start=1):
        where = f"{source}: robot {index}"
        if isinstance(entry.get("id"), str) and ID_PATTERN.fullmatch(entry["id"]):
            where += f" (id {entry['id']!r})"
        unknown = sorted(set(entry) - set(LINK_KEYS) - set(CALIBRATION_KEYS) - set(SERVICES))
        if unknown:
            known = ", ".join((*LINK_KEYS, *CALIBRATION_KEYS)) + " and the tables " + ", ".join(f"[robot.{s}]" for s in SERVICES)
            raise ConfigError(f"{where}: unknown key {unknown[0]!r}; known: {known}")
        robot_id = _need(entry, where, "id", str)
        if not ID_PATTERN.fullmatch(robot_id):
            shown = repr(robot_id) if len(robot_id) <= 80 else f"of {len(robot_id)} characters"
            raise ConfigError(f"{where}: id {shown} must be 1 to 64 letters, digits, '-' or '_' (one key chunk, e.g. r1)")
        host = _need(entry, where, "host", str, "127.0.0.1")
        ports = {name: _need(entry, where, name, int) for name in ("control_port", "log_port")}
        for name, port in ports.items():
            if not 0 <= port <= 65535:
                raise ConfigError(f"{where}: {name} {port} is not a TCP port")
        prefix = _need(entry, where, "prefix", str, f"{FLEET_ROOT}/{robot_id}")
        try:
            validate_prefix(prefix)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        calibration: dict[str, float] = {}
        for name in CALIBRATION_KEYS:
            if name in entry:
                value = entry[name]
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
                    raise ConfigError(f"{where}: {name} must be a positive number, got {value!r}")
                calibration[name] = float(value)
        tables = {}
        for service in SERVICES:
            if service in entry:
                if not isinstance(entry[service], dict):
                    raise ConfigError(f"{where}: {service} must be a table [robot.{service}] of {service} settings")
                tables[service] = {str(k).replace("-", "_"): v for k, v in entry[service].items()}
        robot = FleetRobot(index, robot_id, host, ports["control_port"], ports["log_port"], prefix, calibration, tables)
        for kind, value in (("id", robot_id), ("prefix", prefix), *(("port", (host, p)) for p in ports.values() if p)):
            other = seen.get((kind, value))
            if other is not None:
                shown = f"{value[0]}:{value[1]}" if kind == "port" else repr(value)
                raise ConfigError(f"{where}: {kind} {shown} is already used by robot {other.index}")
            seen[(kind, value)] = robot
        robots.append(robot)
    return robots


def load_fleet(path: str | Path) -> list[FleetRobot]:
    data = read_config(Path(path), "fleet file", toml=True)
    return parse_fleet(data, f"fleet file {path}")


def refuse_single_robot_options(given: Mapping[str, object], loaded: object, options: Mapping[str, str]) -> None:
    """ConfigError, one sentence, for a setting in ``options`` (name -> why) that names one robot, given with --fleet.

    ``given``: the command line's values (None: not given); ``loaded``: the settings as loaded, so a settings file or
    the environment is caught too.
    """
    defaults = type(loaded)()
    for name, why in options.items():
        if given.get(name) is not None:
            raise ConfigError(f"--{name.replace('_', '-')} is for one robot and cannot be used with --fleet: {why}")
        if getattr(loaded, name) != getattr(defaults, name):
            raise ConfigError(
                f"{name} (from the settings file or BLACKMETAL_{name.upper()}) is for one robot and cannot be used with --fleet: {why}"
            )


def numbered_fleet(count: int, host: str = "127.0.0.1", first_port: int = 0) -> list[FleetRobot]:
    """``r1`` ... ``rN`` under ``fleet/<id>``: ports from ``first_port`` on (control, log in pairs), or 0 = any free port."""
    if count < 1:
        raise ConfigError(f"a fleet needs at least one robot, got {count}")
    robots = []
    for k in range(1, count + 1):
        control, log = (first_port + 2 * (k - 1), first_port + 2 * (k - 1) + 1) if first_port else (0, 0)
        robots.append(FleetRobot(k, f"r{k}", host, control, log, f"{FLEET_ROOT}/r{k}"))
    return robots


def write_fleet(robots: list[FleetRobot]) -> str:
    """A fleet file (TOML) for ``robots``: what ``blackmetal sim --robots N`` prints for the other processes.

    Beyond MAX_ROBOTS it says ``max_robots``: the one who asked for N robots meant them (``up --robots 300``).
    """
    lines: list[str] = [f"max_robots = {len(robots)}", ""] if len(robots) > MAX_ROBOTS else []
    for robot in robots:
        lines += ["[[robot]]", f'id = "{robot.id}"', f'host = "{robot.host}"', f"control_port = {robot.control_port}"]
        lines += [f"log_port = {robot.log_port}", f'prefix = "{robot.prefix}"']
        lines += [f"{name} = {value!r}" for name, value in robot.calibration.items()]
        for service, table in robot.tables.items():
            lines.append(f"[robot.{service}]")
            lines += [f"{name} = {value!r}" if not isinstance(value, str) else f'{name} = "{value}"' for name, value in table.items()]
        lines.append("")
    return "\n".join(lines)
