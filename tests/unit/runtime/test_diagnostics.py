"""The one diagnostics severity table (blackmetal.runtime.diagnostics), shared by ROS 2 and Foxglove."""

from blackmetal.runtime import diagnostics as d
from blackmetal.runtime.diagnostics import Level, Status


def test_an_engaged_estop_is_an_error() -> None:
    # the robot cannot move until a person acts
    assert d.ESTOP_ENGAGED.level is Level.ERROR
    assert d.ESTOP_ENGAGED.check(origin=" since then by robot/estop") == (Level.ERROR, "e-stop engaged since then by robot/estop")


def test_levels_order_worst_last() -> None:
    assert [int(level) for level in (Level.OK, Level.WARN, Level.ERROR, Level.STALE)] == [0, 1, 2, 3]


def test_links_connected_ok_connecting_warn_else_error() -> None:
    assert d.link_level("connected") is Level.OK
    assert d.link_level("connecting") is Level.WARN
    assert d.link_level("disconnected") is Level.ERROR
    assert d.CONTROL_LINK_DOWN.check(state="connecting") == (Level.ERROR, "control link connecting")
    assert d.LOG_LINK_DOWN.check(state="connecting") == (Level.WARN, "log link connecting")


def test_graded_conditions_take_their_severe_level() -> None:
    assert d.POLL_SLOW.check(hz=40, asked=50) == (Level.WARN, "polling at 40 Hz of 50 Hz")
    assert d.POLL_SLOW.check(True, hz=20, asked=50) == (Level.ERROR, "polling at 20 Hz of 50 Hz")
    assert d.ROUND_TRIP_SLOW.check(True, ms=300.4) == (Level.ERROR, "round trip 300 ms")
    assert d.REPLIES_LOST.check(lost=1, polls=200, window=10.0) == (Level.WARN, "1 of 200 replies lost in 10 s")
    assert d.SAMPLES_REJECTED.check(True, count=25, window=10.0)[0] is Level.ERROR
    assert d.BAD_ROS_INPUTS.check(True, count=1, window=10.0, key="k")[0] is Level.WARN  # not graded: stays WARN


def test_the_rest_of_the_table_keeps_its_levels() -> None:
    assert d.CONFLICT.check(other="tok", prefix="robot") == (Level.ERROR, "another gateway (tok) on robot: commands refused")
    assert d.COMMANDS_REFUSED.check(other="tok") == (Level.ERROR, "refused: another gateway (tok) on this prefix")
    assert d.REPLIES_LOST_EVER is Level.WARN
    assert d.GATEWAY_NOT_RUNNING.level is d.ODOMETRY_NOT_RUNNING.level is Level.ERROR
    assert {d.NO_HEALTH_YET.level, d.HEALTH_STALE.level, d.NO_POSE_YET.level, d.POSE_STALE.level} == {Level.STALE}
    assert d.POSE_LATE.level is d.CALLS_FAILED.level is Level.WARN
    assert d.POSE_LATE_S < d.POSE_STALE_S and d.POLL_ERROR_RATIO < d.POLL_WARN_RATIO and d.RTT_WARN_MS < d.RTT_ERROR_MS


def test_worst_takes_the_worst_level_and_lists_reasons_worst_first() -> None:
    status = d.worst("n", "hw", [d.LOG_LINK_DOWN.check(state="connecting"), d.ESTOP_ENGAGED.check(origin="")], "fine", [("k", "v")])
    assert status == Status(Level.ERROR, "n", "e-stop engaged; log link connecting", "hw", (("k", "v"),))
    assert d.worst("n", "hw", [], "fine") == Status(Level.OK, "n", "fine", "hw")
