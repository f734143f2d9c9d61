"""params: NAME=VALUE parsed as JSON where it can be, and the table of parameters."""

from __future__ import annotations

import pytest

from blackmetal.schemas import Param
from blackmetal.tools.client import ToolError
from blackmetal.tools.params import parse_assignment, render


def test_an_assignment_is_read_as_json_else_as_text() -> None:
    assert parse_assignment("max_wheel_speed=0.3") == ("max_wheel_speed", 0.3)
    assert parse_assignment("latched=true") == ("latched", True)
    assert parse_assignment("mode=fast") == ("mode", "fast")
    with pytest.raises(ToolError, match="is not NAME=VALUE"):
        parse_assignment("max_wheel_speed")
    with pytest.raises(ToolError, match="a value is a number, true/false or text"):
        parse_assignment("x=[1, 2]")


def test_the_table_shows_bounds_or_read_only() -> None:
    params = [
        Param(name="max_wheel_speed", type="double", value=0.5, min=0.0, max=1.0, description="the limit"),
        Param(name="robot", type="string", value="127.0.0.1", read_only=True),
    ]
    first, second = render(params).splitlines()
    assert first.startswith("max_wheel_speed  0.5") and "0 .. 1" in first and first.endswith("the limit")
    assert second.startswith("robot            127.0.0.1") and "read-only" in second
