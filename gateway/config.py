"""Typed settings with one precedence: command line > environment > file > defaults.

Shared by the gateway and the odometry service. A settings file is TOML
(``.toml``) or JSON5 (``.json5``/``.json``) holding the same names as the
long command-line options (``poll_hz`` or ``poll-hz``); the environment uses
``BLACKMETAL_<NAME>`` (``BLACKMETAL_POLL_HZ=100``). The Zenoh part is the
usual Zenoh flags (``mode``, ``connect``, ``listen``, ``config``,
``no_multicast_scouting``) under the same rules.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import msgspec

from .errors import ConfigError

T = TypeVar("T")

ENV_PREFIX = "BLACKMETAL_"
ZENOH_KEYS = ("mode", "connect", "listen", "config", "no_multicast_scouting")


def loads_json5(text: str) -> Any:
    """Parse the JSON5 people write in config files: comments, trailing commas, bare keys, single quotes."""
    out: list[str] = []
    i, n = 0, len(text)
    while i < n:
        ch = text[i]
        if ch in "\"'":
            j = i + 1
            while j < n and text[j] != ch:
                j += 2 if text[j] == "\\" else 1
            body = text[i + 1 : j]
            if ch == "'":
                body = body.replace('\\"', '"').replace('"', '\\"').replace("\\'", "'")
            out.append('"' + body + '"')
            i = j + 1
        elif text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            if j < 0:
                raise ConfigError("unterminated /* comment")
            i = j + 2
        else:
            out.append(ch)
            i += 1
    cleaned = "".join(out)
    cleaned = re.sub(r",(\s*[}\]])", r"\1", cleaned)
    cleaned = re.sub(r'([{,]\s*)([A-Za-z_$][\w$-]*)\s*:', r'\1"\2":', cleaned)
    try:
        return json.loads(cleaned)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"not valid JSON5: {exc}") from None


def read_settings_file(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read settings file {path}: {exc.strerror}") from None
    try:
        data = tomllib.loads(text) if path.suffix == ".toml" else loads_json5(text)
    except (tomllib.TOMLDecodeError, ConfigError) as exc:
        raise ConfigError(f"settings file {path}: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"settings file {path} must hold an object/table of settings")
    return {key.replace("-", "_"): value for key, value in data.items()}


def _from_env(names: list[str], environ: Mapping[str, str]) -> dict[str, Any]:
    found: dict[str, Any] = {}
    for name in names:
        value = environ.get(ENV_PREFIX + name.upper())
        if value is None:
            continue
        if name in ("connect", "listen"):
            found[name] = [item.strip() for item in value.split(",") if item.strip()]
        elif value.lower() in ("true", "false") and name == "no_multicast_scouting":
            found[name] = value.lower() == "true"
        elif value.lower() in ("none", "off", ""):
            found[name] = None
        else:
            found[name] = value
    return found


def load_settings(
    cls: type[T],
    cli: Mapping[str, Any],
    settings_file: str | None = None,
    environ: Mapping[str, str] | None = None,
) -> T:
    """Build ``cls`` (a dataclass) from defaults < file < environment < command line.

    ``cli`` holds only the options actually given. Unknown names in the file
    and values of the wrong type are errors that name the setting.
    """
    names = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]
    merged: dict[str, Any] = {}
    if settings_file:
        from_file = read_settings_file(settings_file)
        unknown = sorted(set(from_file) - set(names))
        if unknown:
            raise ConfigError(f"settings file {settings_file}: unknown settings {unknown}; known: {names}")
        merged.update(from_file)
    merged.update(_from_env(names, os.environ if environ is None else environ))
    merged.update({key: value for key, value in cli.items() if key in names and value is not None})
    try:
        settings = msgspec.convert(merged, cls, strict=False)
    except msgspec.ValidationError as exc:
        raise ConfigError(f"invalid setting: {exc}") from None
    check = getattr(settings, "check", None)
    if callable(check):
        check()
    return settings


def given_options(args: Any) -> dict[str, Any]:
    """The options present in an argparse namespace built with ``argument_default=SUPPRESS``."""
    return {key: value for key, value in vars(args).items() if not key.startswith("_") and key not in ("func", "command")}
