"""``blackmetal foxglove`` settings: the defaults, and each bound refused in one sentence."""

from __future__ import annotations

import pytest

from blackmetal.foxglove.main import build_parser
from blackmetal.foxglove.settings import FoxgloveSettings
from blackmetal.runtime.settings import load_settings
from blackmetal.schemas import ConfigError


def test_the_defaults_serve_on_the_loopback_and_the_options_override_them() -> None:
    default = load_settings(FoxgloveSettings, build_parser().parse_args([]), environ={})
    assert (default.host, default.port, default.mcap, default.path_length, default.call_timeout) == ("127.0.0.1", 8765, None, 2000, 2.0)
    given = build_parser().parse_args(["--port", "0", "--mcap", "v.mcap", "--path-length", "10", "--call-timeout", "0.5"])
    settings = load_settings(FoxgloveSettings, given, environ={})
    assert (settings.port, settings.mcap, settings.path_length, settings.call_timeout) == (0, "v.mcap", 10, 0.5)


@pytest.mark.parametrize(
    "change, sentence",
    [
        ({"port": 70000}, "--port must be 0..65535, got 70000"),
        ({"path_length": 1}, "--path-length must be at least 2, got 1"),
        ({"call_timeout": 0.05}, "--call-timeout must be 0.1..60 s, got 0.05"),
        ({"call_timeout": 61.0}, "--call-timeout must be 0.1..60 s, got 61"),
    ],
)
def test_a_setting_out_of_its_bounds_is_one_sentence(change: dict[str, object], sentence: str) -> None:
    settings = FoxgloveSettings(**change)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=sentence.replace(".", r"\.")):
        settings.check()


def test_a_bad_prefix_is_refused() -> None:
    with pytest.raises(ConfigError):
        FoxgloveSettings(prefix="a/*").check()
