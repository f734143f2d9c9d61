"""The navigation's parameters: ranges, live sets that refuse with a reason, the table, the gateway's limits."""

from __future__ import annotations

import math

import pytest

from blackmetal.nav.controller import Limits
from blackmetal.nav.params import PARAM_SPECS, READ_ONLY, GatewayLimits, NavParams, effective_limits
from blackmetal.schemas import ConfigError, GatewayParams, Param


def test_the_defaults_are_the_issues_and_pass_their_own_check() -> None:
    p = NavParams()
    p.check()
    assert (p.max_speed, p.max_turn, p.linear_accel, p.angular_accel) == (0.3, 1.2, 0.5, 2.0)
    assert p.xy_tolerance == 0.01 and p.yaw_tolerance == pytest.approx(math.radians(1))
    assert (p.max_goal_distance, p.override_timeout, p.pose_timeout, p.no_progress_timeout, p.feedback_hz) == (100.0, 2.0, 0.3, 10.0, 10.0)
    assert set(PARAM_SPECS) == {f for f in NavParams.__slots__}  # every field is a live parameter


@pytest.mark.parametrize(
    ("field", "value", "words"),
    [
        ("max_speed", 0.0, "within 0.01..1"),
        ("feedback_hz", 2.0, "within 5..50"),
        ("pose_timeout", math.nan, "within"),
        ("max_turn", math.inf, "within"),
    ],
)
def test_a_setting_out_of_range_is_a_config_error_naming_it(field: str, value: float, words: str) -> None:
    with pytest.raises(ConfigError, match=f"{field} must be {words}"):
        NavParams(**{field: value}).check()  # type: ignore[arg-type]


def test_a_live_set_changes_one_value_or_says_why_not() -> None:
    p = NavParams()
    q, refused = p.with_value("max_speed", 0.2)
    assert refused is None and q.max_speed == 0.2 and p.max_speed == 0.3  # frozen: a new record
    q, refused = p.with_value("feedback_hz", 20)  # an integer is a number
    assert refused is None and q.feedback_hz == 20.0 and isinstance(q.feedback_hz, float)
    for name, value, words in [
        ("max_speed", 5.0, "max_speed must be within 0.01..1, got 5.0"),
        ("max_speed", "fast", "max_speed takes a number, got 'fast'"),
        ("max_speed", True, "takes a number"),
        ("xy_tolerance", -1, "within"),
        ("warp", 9, "no parameter 'warp': the navigation's parameters are max_speed, max_turn"),
        ("effective.max_speed", 0.1, "read-only"),
    ]:
        same, refused = p.with_value(name, value)
        assert same is p and refused is not None and words in refused


def test_the_table_lists_live_parameters_then_the_limits_in_use() -> None:
    table = NavParams(max_speed=0.25).table(Limits(max_speed=0.2))
    names = [row.name for row in table]
    assert names == [*PARAM_SPECS, *READ_ONLY]
    row = table[0]
    assert (row.name, row.type, row.value, row.min, row.max, row.read_only) == ("max_speed", "double", 0.25, 0.01, 1.0, False)
    effective = {row.name: row for row in table if row.read_only}
    assert effective["effective.max_speed"].value == 0.2 and effective["effective.angular_accel"].value == 2.0
    assert all(row.description for row in table)


def gateway(**values: float | str) -> GatewayParams:
    return GatewayParams(0.0, [Param(name, "double", value) for name, value in values.items()])


def test_the_gateways_limits_bound_the_navigations() -> None:
    limits = GatewayLimits.of(gateway(max_wheel_speed=0.4, linear_accel=0.3, angular_accel=0.0, wheel_separation=0.5, robot="x"))
    assert limits == GatewayLimits(0.4, 0.3, None, 0.5)  # an acceleration of 0 is no limit
    use = effective_limits(NavParams(), limits)
    assert use.max_speed == 0.3 and use.linear_accel == 0.3 and use.angular_accel == 2.0
    assert use.max_turn == pytest.approx(1.2)  # 0.4 m/s at 0.25 m from the middle is 1.6 rad/s: 1.2 stays
    assert use.latency == 1  # the gateway's ramp steps on its polls too: measured, it costs no whole period
    slow = effective_limits(NavParams(), GatewayLimits.of(gateway(max_wheel_speed=0.1)))
    assert slow.max_speed == 0.1 and slow.max_turn == pytest.approx(0.4) and slow.max_wheel_speed == 0.1
    assert slow.latency == 1
    assert effective_limits(NavParams(), GatewayLimits()) == Limits()  # nothing heard from the gateway: the navigation's own


def test_rows_that_are_missing_or_not_positive_numbers_keep_the_defaults() -> None:
    assert GatewayLimits.of(gateway(max_wheel_speed="fast", linear_accel=-1.0, wheel_separation=math.nan)) == GatewayLimits()
