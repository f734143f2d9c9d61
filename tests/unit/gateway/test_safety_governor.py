"""Gateway core, pure: kinematics, the safety governor on a fake clock, reply pairing, rate limits, settings."""

from __future__ import annotations

import itertools

import json5
import pytest
from hypothesis import given
from hypothesis import strategies as st

from blackmetal import wire
from blackmetal.gateway.exchange import Completed, Exchange, Lost
from blackmetal.gateway.safety import CommandReason, Driving, EStopped, Governor, Offline, Robot, SafetySettings, Sent
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.robot_model import WheelGain, WheelSpeeds, twist_to_wheels, wheels_to_twist
from blackmetal.runtime.reports import ReportLimiter
from blackmetal.runtime.settings import load_settings
from blackmetal.schemas import ConfigError, Twist, Vector3
from blackmetal.wire import CommandCode, Malformed, StatusReply

OK = StatusReply("RECIEVE_OK")
FULL = StatusReply("FULL_BUFFER")


def twist(v: float = 0.0, w: float = 0.0) -> Twist:
    return Twist(linear=Vector3(x=v), angular=Vector3(z=w))


# ----------------------------------------------------------------------------- kinematics


def test_left_turn_drives_the_right_wheel_faster() -> None:
    wheels, scaled = twist_to_wheels(0.2, 0.4, 0.5, 0.8)
    assert wheels == WheelSpeeds(right=pytest.approx(0.3), left=pytest.approx(0.1))  # type: ignore[arg-type]
    assert not scaled


def test_too_fast_commands_are_scaled_keeping_the_curvature() -> None:
    wheels, scaled = twist_to_wheels(1.0, 2.0, 0.5, 0.8)
    assert scaled
    assert max(abs(wheels.right), abs(wheels.left)) == pytest.approx(0.8)
    v, w = wheels_to_twist(wheels.left, wheels.right, 0.5)
    assert w / v == pytest.approx(2.0 / 1.0)  # same arc, only slower


@given(
    st.floats(min_value=-10, max_value=10, allow_nan=False),
    st.floats(min_value=-50, max_value=50, allow_nan=False),
)
def test_wheels_never_exceed_the_limit_and_keep_the_curvature(v: float, w: float) -> None:
    wheels, _ = twist_to_wheels(v, w, 0.5, 0.8)
    assert abs(wheels.right) <= 0.8 + 1e-12 and abs(wheels.left) <= 0.8 + 1e-12
    v2, w2 = wheels_to_twist(wheels.left, wheels.right, 0.5)
    if abs(v) > 1e-6 and abs(v2) > 1e-9:
        assert w2 / v2 == pytest.approx(w / v, rel=1e-6, abs=1e-9)


# ----------------------------------------------------------------------------- governor


def governor(**overrides: object) -> Governor:
    gov = Governor(SafetySettings(**overrides))  # type: ignore[arg-type]
    gov.on_link_up(0.0)
    return gov


def test_the_governor_is_in_one_named_state() -> None:
    gov = Governor(SafetySettings())
    assert gov.state == Offline() and isinstance(gov.state, Offline)
    gov.on_link_up(0.0)
    assert gov.state == Driving(Robot(), current_at=0.0) and isinstance(gov.state, Driving)
    gov.next_command(0.0)
    gov.on_estop(True, 1.0)  # EMG_STOP due at once; as far as velocity goes, standstill was sent
    assert gov.state == EStopped(Robot(sent=Sent(WheelSpeeds(left=0.0, right=0.0), 0.0)), emg_at=1.0)
    assert gov.emg_stop_due(1.0) and gov.next_deadline() == 1.0
    gov.on_emg_stop_sent()
    assert not gov.emg_stop_due(1.0) and gov.next_deadline() == float("inf")
    gov.on_link_down()
    assert gov.state == Offline(estop=True)
    gov.on_link_up(2.0)  # latched across the reconnect: EMG_STOP again
    assert gov.state == EStopped(Robot(), emg_at=2.0)
    gov.on_estop(False, 3.0)
    assert gov.state == Driving(Robot(), current_at=3.0)


def test_link_up_sends_zero_then_commands_are_sent_once() -> None:
    gov = governor()
    first = gov.next_command(0.0)
    assert first is not None and first.wheels == WheelSpeeds(left=0.0, right=0.0)
    assert gov.next_command(0.01) is None
    assert gov.on_twist(twist(0.2), 0.02) is None
    cmd = gov.next_command(0.02)
    assert cmd is not None and cmd.wheels == WheelSpeeds(left=0.2, right=0.2) and cmd.reason is CommandReason.NEW
    gov.on_twist(twist(0.2), 0.1)  # unchanged: not re-sent
    assert gov.next_command(0.1) is None


def test_calibrated_wheels_are_asked_for_what_makes_them_true() -> None:
    # a left wheel 1.5 % larger than its drawing: the robot's firmware would run it 1.5 % fast, so it is asked for less
    gov = governor(wheel_gain=WheelGain(left=1 / 1.015, right=1.0))
    gov.next_command(0.0)
    gov.on_twist(twist(0.3), 0.01)
    cmd = gov.next_command(0.01)
    assert cmd is not None and cmd.wheels == WheelSpeeds(left=round(0.3 / 1.015, 6), right=0.3)


def test_gateway_settings_turn_calibrated_impulses_into_the_gain(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from blackmetal import robot_model as model
    from blackmetal.gateway.settings import GatewaySettings
    from blackmetal.runtime.settings import load_settings
    from blackmetal.schemas import ConfigError

    calibration = tmp_path / "calibration.toml"
    calibration.write_text(
        f"wheel_separation = 0.515\nimpulses_left = {model.IMPULSES_PER_METER_LEFT / 1.015}\nimpulses_right = {model.IMPULSES_PER_METER_RIGHT}\n"
    )
    safety = load_settings(GatewaySettings, {}, str(calibration), environ={}).safety()
    assert safety.wheel_separation == 0.515 and (safety.wheel_gain.left, safety.wheel_gain.right) == pytest.approx((1 / 1.015, 1.0))
    with pytest.raises(ConfigError, match="impulses_left"):
        load_settings(GatewaySettings, {"impulses_left": 5.0}, environ={})


def test_command_timeout_brakes_and_shows_in_state() -> None:
    gov = governor(cmd_timeout=0.5)
    gov.next_command(0.0)
    gov.on_twist(twist(0.3), 1.0)
    assert gov.next_command(1.0).wheels == WheelSpeeds(left=0.3, right=0.3)  # type: ignore[union-attr]
    assert gov.next_command(1.499) is None and not gov.timed_out(1.499)
    assert gov.next_deadline() == 1.5  # the brake has its own deadline
    brake = gov.next_command(1.5)
    assert brake is not None and brake.wheels == WheelSpeeds(left=0.0, right=0.0)
    assert gov.timed_out(1.5)
    gov.on_twist(twist(0.1), 2.0)
    assert not gov.timed_out(2.0)


def test_timeout_zero_disables_it_and_keepalive_repeats_motion() -> None:
    gov = governor(cmd_timeout=0.0, keepalive=5.0)
    gov.next_command(-1.0)
    gov.on_twist(twist(0.2), 0.0)
    gov.next_command(0.0)
    sent = [t for t in range(1, 31) if (c := gov.next_command(float(t))) is not None and c.reason is CommandReason.KEEPALIVE]
    assert sent == [5, 10, 15, 20, 25, 30]  # the robot's 10 s watchdog never fires


def test_zero_velocity_needs_no_keepalive() -> None:
    gov = governor(cmd_timeout=0.0)
    gov.next_command(0.0)
    assert all(gov.next_command(float(t)) is None for t in range(1, 30))


def test_estop_latches_refuses_commands_and_releases() -> None:
    gov = governor()
    gov.next_command(0.0)
    gov.on_twist(twist(0.3), 0.0)
    gov.next_command(0.0)
    gov.on_estop(True, 0.0)
    assert gov.emg_stop_due(0.0)
    assert gov.next_command(0.1) is None
    reason = gov.on_twist(twist(0.3), 0.1)
    assert reason is not None and "emergency stop" in reason
    gov.on_estop(False, 0.2)
    assert gov.next_command(0.2) is None  # release alone does not move the robot
    assert gov.on_twist(twist(0.1), 0.3) is None
    assert gov.next_command(0.3).wheels == WheelSpeeds(left=0.1, right=0.1)  # type: ignore[union-attr]


def test_link_down_refuses_and_reconnect_never_resumes_old_motion() -> None:
    gov = governor()
    gov.next_command(0.0)
    gov.on_twist(twist(0.3), 0.0)
    gov.next_command(0.0)
    gov.on_link_down()
    assert "link is down" in (gov.on_twist(twist(0.3), 0.1) or "")
    assert gov.next_command(0.1) is None
    gov.on_link_up(0.2)
    assert gov.next_command(0.2).wheels == WheelSpeeds(left=0.0, right=0.0)  # type: ignore[union-attr]


def test_estop_latched_across_a_reconnect_is_reasserted() -> None:
    gov = governor()
    gov.on_estop(True, 0.0)
    gov.on_emg_stop_sent()
    gov.on_link_down()
    gov.on_link_up(1.0)
    assert gov.emg_stop_due(1.0)


def test_motion_retries_are_spaced_growing_and_bounded() -> None:
    gov = governor(full_buffer_retries=3, cmd_timeout=0.0)
    gov.next_command(-1.0)
    gov.on_twist(twist(0.2), 0.0)
    cmd = gov.next_command(0.0)
    assert cmd is not None
    now, times = 0.0, []
    for _ in range(10):
        reason = gov.on_dropped(cmd.wheels, now)
        if reason is not None:
            assert "given up" in reason
            break
        assert gov.next_command(now) is None  # never at once: spaced
        now = gov.next_deadline()
        again = gov.next_command(now)
        assert again is not None and again.reason is CommandReason.RETRY and again.wheels == cmd.wheels
        times.append(now)
    assert len(times) == 3
    gaps = [b - a for a, b in zip([0.0, *times], times, strict=False)]
    assert gaps == pytest.approx([0.005, 0.010, 0.020])
    assert gov.on_dropped(WheelSpeeds(left=0.5, right=0.5), now) is None  # a superseded command is not retried


def test_a_stop_is_never_given_up_and_never_faster_than_50_a_second() -> None:
    gov = governor(full_buffer_retries=3, cmd_timeout=0.5)
    gov.next_command(0.0)
    gov.on_accepted(WheelSpeeds(left=0.0, right=0.0), 0.0)
    gov.on_twist(twist(0.5), 0.01)
    gov.on_accepted(gov.next_command(0.01).wheels, 0.011)  # type: ignore[union-attr]
    brake = gov.next_command(0.51)
    assert brake is not None and brake.wheels.is_zero
    now, sent = 0.51, [0.51]
    while now < 10.51:  # the robot answers FULL_BUFFER to every stop for 10 s
        assert gov.on_dropped(WheelSpeeds(left=0.0, right=0.0), now) is None
        now = gov.next_deadline()
        again = gov.next_command(now)
        assert again is not None and again.wheels.is_zero
        sent.append(now)
    assert len(sent) / 10.0 < 50  # re-sent, spaced, for as long as it takes
    gov.on_accepted(WheelSpeeds(left=0.0, right=0.0), now)
    assert gov.accepted == WheelSpeeds(left=0.0, right=0.0) and gov.next_deadline() == float("inf")


def test_a_robot_that_moves_after_accepting_a_stop_is_asked_again() -> None:
    gov = governor(cmd_timeout=0.0)
    gov.next_command(0.0)
    gov.on_accepted(WheelSpeeds(left=0.0, right=0.0), 0.001)
    gov.observe_motion(0.4, 0.4, 0.1)  # the wheels turn although nothing asks for it
    assert gov.next_command(0.2) is None  # within the grace a stop may still be taking effect
    again = gov.next_command(gov.next_deadline())
    assert again is not None and again.reason is CommandReason.STOP_AGAIN and again.wheels.is_zero
    gov.observe_motion(0.0, 0.0, 1.0)
    assert gov.next_deadline() == float("inf")


def test_a_flood_is_coalesced_to_the_latest_command() -> None:
    gov = governor(max_command_hz=100.0, cmd_timeout=0.0)
    gov.next_command(0.0)
    sent = []
    for i in range(1, 101):  # 100 different commands within 0.1 s (1 kHz)
        now = 1.0 + i * 0.001
        gov.on_twist(twist(0.001 * i), now)
        if (cmd := gov.next_command(now)) is not None:
            sent.append((now, cmd.wheels.left))
    assert len(sent) <= 11  # at most 100 Hz reach the robot
    _, held = gov.plan(1.1)  # the latest one waits for the rate cap, its time is the deadline
    assert held.command is not None and held.at == gov.next_deadline() <= 1.1 + 0.01
    final = gov.next_command(held.at)
    assert final is not None and final.wheels.left == pytest.approx(0.1)  # the latest one, not a backlog


def test_implausible_commands_are_rejected_not_scaled() -> None:
    gov = governor()
    assert "linear.x" in (gov.on_twist(twist(1e22), 0.0) or "")
    assert "angular.z" in (gov.on_twist(twist(0.0, -1e300), 0.0) or "")
    assert gov.on_twist(twist(5.0, 0.0), 0.0) is None  # fast but plausible: scaled
    cmd = gov.next_command(0.0)
    assert isinstance(gov.state, Driving)
    scaled = twist_to_wheels(*gov.state.current, gov.settings.wheel_separation, gov.settings.max_wheel_speed)[1]
    assert cmd is not None and scaled and max(abs(cmd.wheels.left), abs(cmd.wheels.right)) <= 0.8


def test_acceleration_limit_ramps_the_command() -> None:
    gov = governor(linear_accel=0.5, cmd_timeout=0.0)
    gov.next_command(0.0)
    gov.on_twist(twist(0.4), 0.0)
    speeds = []
    for i in range(1, 11):
        cmd = gov.next_command(0.1 * i)
        if cmd is not None:
            speeds.append(cmd.wheels.left)
    assert speeds[0] == pytest.approx(0.05) and speeds[-1] == pytest.approx(0.4)
    assert all(b - a <= 0.05 + 1e-9 for a, b in itertools.pairwise(speeds))


# ----------------------------------------------------------------------------- exchange


def test_pipelined_requests_pair_with_their_replies() -> None:
    ex = Exchange()
    poll = wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY)
    vel = wire.set_velocity(left=0.1, right=0.1)
    ex.sent(poll, 0.0)
    ex.sent(vel, 0.001)
    assert ex.received(OK, 0.002) == []
    (done,) = ex.received(wire.SpeedReading(left=100, right=-105), 0.003)
    assert isinstance(done, Completed) and done.request == poll and done.data == wire.SpeedReading(left=100, right=-105)
    assert done.rtt == pytest.approx(0.002)
    (done,) = ex.received(OK, 0.004)
    assert done.request == vel and done.data is None


def test_full_buffer_on_a_poll_means_no_data_follows() -> None:
    ex = Exchange()
    ex.sent(wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY), 0.0)
    (done,) = ex.received(FULL, 0.001)
    assert isinstance(done, Completed) and done.status.full_buffer and not ex.outstanding


def test_a_lost_data_reply_costs_one_request_only() -> None:
    ex = Exchange()
    poll = wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY)
    vel = wire.set_velocity(left=0.1, right=0.1)
    ex.sent(poll, 0.0)
    ex.sent(vel, 0.0)
    ex.received(OK, 0.001)
    ex.received(Malformed("garbled", b"{x}"), 0.001)
    lost, done = ex.received(OK, 0.002)
    assert isinstance(lost, Lost) and lost.request == poll
    assert isinstance(done, Completed) and done.request == vel


def test_unanswered_requests_expire_and_unexpected_replies_pair_with_nothing() -> None:
    ex = Exchange(reply_timeout=0.5)
    assert ex.received(OK, 0.0) == [] and not ex.outstanding
    ex.sent(wire.simple(CommandCode.GET_LR_WHEEL_VELOCITY), 0.0)
    assert ex.expire(0.4) == []
    (lost,) = ex.expire(0.6)
    assert "no reply" in lost.reason


# ----------------------------------------------------------------------------- rate limit


def test_error_reports_are_rate_limited_with_a_suppressed_count() -> None:
    limiter = ReportLimiter(rate=5.0, burst=10)
    admitted = [limiter.admit("k", 0.0)[0] for _ in range(100)]
    assert sum(admitted) == 10
    assert limiter.due_summaries(0.0) == []
    assert limiter.due_summaries(1.0) == [("k", 90)]
    ok, suppressed = limiter.admit("other", 1.0)
    assert ok and suppressed == 0


# ----------------------------------------------------------------------------- settings


def test_settings_precedence_cli_over_env_over_file(tmp_path) -> None:  # type: ignore[no-untyped-def]
    toml = tmp_path / "gw.toml"
    toml.write_text('robot = "10.0.0.9"\npoll_hz = 20\ncmd-timeout = 0.8\nprefix = "fleet/a"\n')
    settings = load_settings(GatewaySettings, {"poll_hz": 100.0}, str(toml), environ={"BLACKMETAL_CMD_TIMEOUT": "0.7"})
    assert settings.robot == "10.0.0.9"
    assert settings.poll_hz == 100.0
    assert settings.cmd_timeout == 0.7
    assert settings.prefix == "fleet/a"
    defaults = load_settings(GatewaySettings, {}, environ={})
    assert defaults.robot == "127.0.0.1" and defaults.control_port == 665 and defaults.poll_hz == 50.0


def test_json5_settings_file(tmp_path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "gw.json5"
    path.write_text("{\n  // the lab robot\n  robot: '192.0.2.7',\n  connect: ['tcp/127.0.0.1:7447',],\n  /* fast */ poll_hz: 200,\n}\n")
    settings = load_settings(GatewaySettings, {}, str(path), environ={})
    assert settings.robot == "192.0.2.7" and settings.poll_hz == 200 and settings.zenoh.connect == ["tcp/127.0.0.1:7447"]


@pytest.mark.parametrize("text", ["[1, 2,]", "x, b: y", "x // not a comment", "a /* b */ c", "it's"])
def test_json5_strings_are_taken_verbatim(tmp_path, text: str) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "gw.json5"
    path.write_text(f"{{robot: {json5.dumps(text)}, poll_hz: 20}}")
    settings = load_settings(GatewaySettings, {}, str(path), environ={})
    assert settings.robot == text and settings.poll_hz == 20


@pytest.mark.parametrize(
    "cli, fragment",
    [
        ({"poll_hz": 0.0}, "poll_hz"),
        ({"poll_hz": "fast"}, "poll_hz"),
        ({"max_wheel_speed": 3.0}, "max_wheel_speed"),
        ({"keepalive": 12.0}, "keepalive"),
        ({"prefix": "robot/*"}, "prefix"),
        ({"control_port": 70000}, "control_port"),
        ({"cmd_timeout": -1.0}, "cmd_timeout"),
    ],
)
def test_bad_settings_name_the_setting(cli: dict[str, object], fragment: str) -> None:
    with pytest.raises(ConfigError, match=fragment):
        load_settings(GatewaySettings, cli, environ={})


def test_unknown_setting_in_a_file_is_an_error(tmp_path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "gw.toml"
    path.write_text("pol_hz = 20\n")
    with pytest.raises(ConfigError, match="pol_hz"):
        load_settings(GatewaySettings, {}, str(path), environ={})


def test_a_setting_of_the_wrong_kind_is_said_in_plain_words_naming_where_it_came_from(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from blackmetal.schemas import ConfigError

    toml = tmp_path / "gw.toml"
    toml.write_text('poll_hz = "fast"\n')
    with pytest.raises(ConfigError, match=rf"settings file {toml}: poll_hz must be a number, got 'fast' \(text\)"):
        load_settings(GatewaySettings, {}, str(toml), environ={})
    with pytest.raises(ConfigError, match=r"BLACKMETAL_CMD_TIMEOUT: cmd_timeout must be a number, got 'soon' \(text\)"):
        load_settings(GatewaySettings, {}, environ={"BLACKMETAL_CMD_TIMEOUT": "soon"})
