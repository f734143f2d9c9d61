"""Typed settings with one precedence: command line > environment (``BLACKMETAL_<NAME>``) > file > defaults.

One settings dataclass per process, fields declared with :func:`setting`: its options, their help and the names a TOML
or JSON5 file may use come from them. The Zenoh flags are its ``zenoh`` field, under the same rules.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import json5
import msgspec

from blackmetal.schemas import ConfigError

from .zenoh_setup import ZenohSettings

T = TypeVar("T")

ENV_PREFIX = "BLACKMETAL_"
#: Options that are not settings: they choose the file, or belong to the command itself.
NOT_SETTINGS = frozenset({"settings", "func", "command"})


def setting(default: Any = dataclasses.MISSING, help: str = "", *, factory: Any = None, **option: Any) -> Any:
    """A settings field with the help text and argparse details of its command-line option.

    ``option`` may hold ``metavar``, ``choices``, ``flag`` (a different option string, e.g. ``--no-mirror-right``) and
    ``const`` (for such a flag), ``comma=True`` for a list given as one comma-separated option (``--map-pose 1,2,0``, as
    its environment variable is), or ``cli=False`` for a field with no option.
    """
    metadata = {"help": help, **option}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def _fields(cls: type) -> list[dataclasses.Field[Any]]:
    return [f for f in dataclasses.fields(cls) if f.name != "zenoh"]


def _default(f: dataclasses.Field[Any]) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def default_of(cls: type, name: str) -> Any:
    """The default of setting ``name`` of the settings dataclass ``cls``: for a tool that starts the service and shows it."""
    found = [_default(f) for f in dataclasses.fields(cls) if f.name == name]
    if not found:
        raise ValueError(f"{cls.__name__} has no setting {name!r}")
    if found[0] is dataclasses.MISSING:
        raise ValueError(f"{cls.__name__}.{name} has no default")
    return found[0]


def _default_text(f: dataclasses.Field[Any]) -> str:
    value = _default(f)
    if value is dataclasses.MISSING or value is None or value == [] or value is False:
        return ""
    if isinstance(value, list) and f.metadata.get("comma"):
        return f" (default {','.join(f'{v:g}' if isinstance(v, float) else str(v) for v in value)})"
    return f" (default {value:g})" if isinstance(value, float) else f" (default {value})"


def add_setting_arguments(parser: argparse.ArgumentParser, cls: type) -> None:
    """One option per field of ``cls``; unset options stay None so files and the environment can fill them."""
    hints = typing.get_type_hints(cls)
    parser.add_argument("--settings", metavar="FILE", help="settings file (TOML or JSON5) with the option names as keys")
    for f in _fields(cls):
        meta = f.metadata
        if meta.get("cli", True) is False:
            continue
        flag = meta.get("flag", "--" + f.name.replace("_", "-"))
        kwargs: dict[str, Any] = {"dest": f.name, "default": None, "help": meta.get("help", "") + _default_text(f)}
        kind = hints[f.name]
        args = [a for a in typing.get_args(kind) if a is not type(None)]
        if isinstance(kind, types.UnionType) and len(args) == 1:
            kind = args[0]
        if kind is bool:
            kwargs.update(action="store_const", const=meta.get("const", True))
            if "const" in meta:
                kwargs["help"] = meta.get("help", "")
        elif typing.get_origin(kind) is list and meta.get("comma"):
            kwargs.update(type=comma_list, metavar=meta.get("metavar", "A,B"))
        elif typing.get_origin(kind) is list:
            kwargs.update(action="append", metavar=meta.get("metavar", "VALUE"))
        else:
            kwargs.update(type=kind, metavar=meta.get("metavar", f.name.upper()))
            if "choices" in meta:
                kwargs["choices"] = meta["choices"]
        parser.add_argument(flag, **kwargs)


def comma_list(text: str) -> list[str]:
    """``1,2,0`` as ``["1", "2", "0"]`` (the settings model converts each item); empty or ``none``: an empty list."""
    if text.strip().lower() in ("", "none", "off"):
        return []
    return [item.strip() for item in text.split(",")]


def read_config(path: Path, what: str, toml: bool) -> Any:
    """The TOML (else JSON5) file at ``path``; a ConfigError naming ``what`` it is when it cannot be read or parsed."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read {what} {path}: {exc.strerror}") from None
    try:
        return tomllib.loads(text) if toml else json5.loads(text)
    except ValueError as exc:  # TOMLDecodeError is one
        raise ConfigError(f"{what} {path} is not valid {'TOML' if toml else 'JSON5'}: {exc}") from None


def read_settings_file(path: str | Path) -> dict[str, Any]:
    """The settings in a TOML or JSON5 file, names with dashes or underscores."""
    path = Path(path)
    data = read_config(path, "settings file", toml=path.suffix == ".toml")
    if not isinstance(data, dict):
        raise ConfigError(f"settings file {path} must hold a table (TOML) or an object (JSON5) of settings")
    return {str(key).replace("-", "_"): value for key, value in data.items()}


def _list_names(cls: type) -> set[str]:
    hints = typing.get_type_hints(cls)
    return {name for name, kind in hints.items() if typing.get_origin(kind) is list}


def load_settings(
    cls: type[T],
    given: argparse.Namespace | Mapping[str, Any],
    settings_file: str | None = None,
    environ: Mapping[str, str] | None = None,
) -> T:
    """Build ``cls`` from defaults < file < environment < ``given`` (options actually set; None = not set).

    ``given`` may be the parsed arguments, whose ``settings`` names the file. Unknown names in the file and values of
    the wrong type are errors that name the setting; so are the checks of the class's ``check()``.
    """
    options = dict(vars(given) if isinstance(given, argparse.Namespace) else given)
    settings_file = settings_file or options.get("settings")
    own = [f.name for f in _fields(cls)]
    has_zenoh = any(f.name == "zenoh" for f in dataclasses.fields(cls))  # type: ignore[arg-type]
    zenoh_names = [f.name for f in dataclasses.fields(ZenohSettings) if f.metadata.get("cli", True)] if has_zenoh else []
    names = own + zenoh_names
    merged: dict[str, Any] = {}
    origin: dict[str, str] = {}  # where each value came from, for the error that names it
    if settings_file:
        from_file = read_settings_file(settings_file)
        unknown = sorted(set(from_file) - set(names))
        if unknown:
            raise ConfigError(f"settings file {settings_file}: unknown settings {unknown}; known: {sorted(names)}")
        merged.update(from_file)
        origin.update(dict.fromkeys(from_file, f"settings file {settings_file}"))
    lists = _list_names(cls) | (_list_names(ZenohSettings) if has_zenoh else set())
    environ = os.environ if environ is None else environ
    from_env: dict[str, Any] = {}
    for name in names:
        value = environ.get(ENV_PREFIX + name.upper())
        if value is None:
            continue
        if name in lists:
            from_env[name] = [item.strip() for item in value.split(",") if item.strip()]
        elif value.lower() in ("none", "off", ""):
            from_env[name] = None
        else:
            from_env[name] = value
    merged.update(from_env)
    origin.update({k: f"BLACKMETAL_{k.upper()}" for k in from_env})
    from_cli = {k: v for k, v in options.items() if k in names and k not in NOT_SETTINGS and v is not None}
    merged.update(from_cli)
    origin.update({k: f"--{k.replace('_', '-')}" for k in from_cli})
    try:
        values = {k: v for k, v in merged.items() if k in own}
        if has_zenoh:
            values["zenoh"] = msgspec.convert({k: v for k, v in merged.items() if k in zenoh_names}, ZenohSettings, strict=False)
        settings = msgspec.convert(values, cls, strict=False)
    except msgspec.ValidationError as exc:
        raise ConfigError(plain_words(str(exc), merged, origin)) from None
    check = getattr(settings, "check", None)
    if callable(check):
        check()
    return settings


_KINDS = {"float": "a number", "int": "an integer", "str": "text", "bool": "true or false", "array": "a list", "null": "nothing"}
_MSGSPEC_TYPE = re.compile(r"Expected `([^`]+)`, got `([^`]+)` - at `\$\.(\w+)")


def plain_words(text: str, values: Mapping[str, Any], origin: Mapping[str, str]) -> str:
    """msgspec's "Expected `float`, got `str` - at `$.poll_hz`" as a person says it, naming where the value came from."""
    found = _MSGSPEC_TYPE.search(text)
    if found is None:
        return f"invalid setting: {text}"
    expected, got, name = found.groups()
    wanted = " or ".join(_KINDS.get(kind.strip(), kind.strip()) for kind in expected.split("|"))
    where = origin.get(name, "the settings")
    return f"{where}: {name} must be {wanted}, got {values.get(name)!r} ({_KINDS.get(got, got)})"


def check_positive(settings: object, names: str) -> None:
    """Raise ConfigError naming the first of the settings ``names`` (separated by spaces) that is set but not positive."""
    for name in names.split():
        value = getattr(settings, name)
        if value is not None and not value > 0:
            raise ConfigError(f"{name} must be positive, got {value}")
