"""Issue #28 without processes: each distro's keys and tokens, the robot model the node publishes, and /odom's covariance
from a calibration's measured residuals (which ``blackmetal calibrate`` now writes and every service still takes)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from blackmetal import robot_model as model
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.odometry_service.batch import integrate
from blackmetal.odometry_service.calibration import Constants, Segment, residual_figures
from blackmetal.odometry_service.settings import OdometrySettings
from blackmetal.robot_model import Encoders, read_calibration
from blackmetal.ros2.core import Ros2Core
from blackmetal.ros2.messages import RosCodec
from blackmetal.ros2.naming import (
    TRANSIENT_LOCAL,
    WITHOUT_TYPE_HASHES,
    Direction,
    Distro,
    NodeIdentity,
    Qos,
    parse_distros,
    rmw_zenoh_data_key,
    topics,
    type_hash_of,
)
from blackmetal.ros2.settings import MIN_VARIANCE, Ros2Settings
from blackmetal.runtime.settings import load_settings
from blackmetal.schemas import ConfigError, Keys
from unit.ros2.test_core import ODOM_HASH, Recorder, encode_impulses
from unit.ros2.test_services import read_diagnostics

NOMINAL = Constants(model.IMPULSES_PER_METER_LEFT, model.IMPULSES_PER_METER_RIGHT, model.WHEEL_SEPARATION)


@pytest.fixture(scope="module")
def codec() -> RosCodec:
    return RosCodec()


def cli(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "blackmetal", *args], capture_output=True, text=True, timeout=120, env=env)


# ------------------------------------------------------------------ each distro's formats
def test_each_distros_keys_and_tokens() -> None:
    """Humble writes TypeHashNotSupported in keys and tokens (rmw_zenoh 0.1.9); Jazzy, Kilted, Lyrical, Rolling the RIHS01 hash."""
    node = NodeIdentity(domain_id=0, zid="abc", name="blackmetal")
    for distro in Distro:
        odom_hash = type_hash_of(distro, ODOM_HASH)
        key = rmw_zenoh_data_key(0, "/odom", "nav_msgs/msg/Odometry", odom_hash)
        token = node.entity_token(3, Direction.PUBLISH, "/odom", "nav_msgs/msg/Odometry", odom_hash, Qos())
        expected = "TypeHashNotSupported" if distro is Distro.HUMBLE else ODOM_HASH
        assert key == f"0/odom/nav_msgs::msg::dds_::Odometry_/{expected}"
        assert token == f"@ros2_lv/0/abc/0/3/MP/%/%/blackmetal/%odom/nav_msgs::msg::dds_::Odometry_/{expected}/::,10:,:,:,,"
        assert (distro in WITHOUT_TYPE_HASHES) is (distro is Distro.HUMBLE)
    # robot_state_publisher's QoS(1).transient_local(): durability 1, depth 1, the rest rmw_zenoh's defaults
    assert TRANSIENT_LOCAL.keyexpr() == ":1:,1:,:,:,,"
    named = {t.key_name: t for t in topics(True, robot_model=True)}
    assert named["robot_description"].qos.is_transient_local and named["tf_static"].qos.is_transient_local
    assert named["robot_description"].full_name("/r2") == "/r2/robot_description"
    assert next(t for t in topics(True, absolute_tf=True, robot_model=True) if t.name == "tf_static").full_name("/r2") == "/tf_static"


def test_distro_lists_and_their_mistakes() -> None:
    assert parse_distros("humble,jazzy") == (Distro.HUMBLE, Distro.JAZZY)
    assert parse_distros(" Jazzy , jazzy,rolling") == (Distro.JAZZY, Distro.ROLLING)
    for bad in ("foxy", "", "humble,iron"):
        with pytest.raises(ConfigError) as info:
            parse_distros(bad)
        assert "\n" not in str(info.value) and "humble, jazzy, kilted, lyrical, rolling" in str(info.value)


@pytest.mark.slow
def test_a_distro_rmw_zenoh_has_no_release_for_is_one_sentence() -> None:
    bad = cli("ros2", "--distro", "foxy", "-l", "tcp/127.0.0.1:0")
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1, bad.stderr
    assert "--distro 'foxy' is not a ROS 2 distro rmw_zenoh is released for" in bad.stderr and "Traceback" not in bad.stderr
    import os

    sourced = cli("ros2", "-l", "tcp/127.0.0.1:0", env={**os.environ, "ROS_DISTRO": "iron"})
    assert sourced.returncode == 2 and "ROS_DISTRO 'iron'" in sourced.stderr and sourced.stderr.count("\n") == 1, sourced.stderr
    up = cli("up", "--distro", "jazzy")
    assert up.returncode == 2 and "--distro is for the ROS 2 adapter: give --ros2 as well" in up.stderr, up.stderr


def test_the_default_distro_is_the_sourced_ones_else_jazzy(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ROS_DISTRO", raising=False)
    assert Ros2Settings().distros() == (Distro.JAZZY,)
    monkeypatch.setenv("ROS_DISTRO", "humble")
    assert Ros2Settings().distros() == (Distro.HUMBLE,)


# ------------------------------------------------------------------ the robot model, as robot_state_publisher publishes it
def test_the_core_publishes_the_robot_model_once_and_the_wheels_with_the_joints(codec: RosCodec) -> None:
    settings = Ros2Settings(wheel_separation=0.47)
    options = settings.options({"cmd_vel": "c", "estop": "e"}, frame_prefix="r2/")
    out = Recorder()
    core = Ros2Core(options, Keys(), out, codec, wallclock=lambda: 1_700_000_000.0)
    core.tick(0.0)
    core.tick(1.0)
    published = [t for t, _ in out.ros_out if t != "diagnostics"]
    assert published == ["robot_description", "tf_static"]  # once: the transient-local publishers keep them
    urdf = codec.decode(out.ros_out[0][1], "std_msgs/msg/String").data
    assert urdf == model.urdf(model.Body(wheel_separation=0.47), frame_prefix="r2/")
    static = codec.decode(out.ros_out[1][1], "tf2_msgs/msg/TFMessage").transforms
    assert [(t.header.frame_id, t.child_frame_id) for t in static] == [("r2/base_footprint", "r2/base_link"), ("r2/base_link", "r2/caster")]
    assert static[0].transform.translation.z == model.WHEEL_RADIUS
    assert options.frames.base == "r2/base_footprint"  # odom -> the URDF's root, one tree
    # the wheels: base_link -> left_wheel / right_wheel turned about +y by the joint angles, stamped like /joint_states
    left, right = Encoders().to_impulses(0.2, 0.1)
    for i in range(11):
        core.on_impulses(encode_impulses(i, 100.0 + 0.1 * i, round(left), round(right)), now=1.0)
    state = codec.decode([c for t, c in out.ros_out if t == "joint_states"][-1], "sensor_msgs/msg/JointState")
    wheels = codec.decode([c for t, c in out.ros_out if t == "tf"][-1], "tf2_msgs/msg/TFMessage").transforms
    assert [(t.header.frame_id, t.child_frame_id) for t in wheels] == [
        ("r2/base_link", "r2/left_wheel"),
        ("r2/base_link", "r2/right_wheel"),
    ]
    assert (wheels[0].header.stamp.sec, wheels[0].header.stamp.nanosec) == (state.header.stamp.sec, state.header.stamp.nanosec)
    for transform, angle, y in zip(wheels, state.position, (0.235, -0.235), strict=True):
        q = transform.transform.rotation
        assert (q.x, q.z) == (0.0, 0.0) and 2 * math.atan2(q.y, q.w) == pytest.approx(angle)
        assert transform.transform.translation.y == pytest.approx(y)


def test_without_the_robot_model_nothing_of_it_is_published_and_a_base_frame_off_the_model_is_refused(codec: RosCodec) -> None:
    options = Ros2Settings(robot_model=False).options({"cmd_vel": "c", "estop": "e"})
    out = Recorder()
    core = Ros2Core(options, Keys(), out, codec)
    core.tick(0.0)
    core.on_impulses(encode_impulses(1, 1.0, 10, -10), now=1.0)
    assert [t for t, _ in out.ros_out] == ["diagnostics", "joint_states"]
    with pytest.raises(ConfigError, match=r"--base-frame base_link: the robot model's root link is base_footprint"):
        Ros2Settings(base_frame="base_link").check()
    Ros2Settings(base_frame="base_link", robot_model=False).check()


# ------------------------------------------------------------------ calibration residuals -> /odom's covariance
def test_residual_figures_are_the_rms_of_the_odometry_against_the_reference() -> None:
    steps = 400
    d = np.full(steps, 0.002)
    d_left, d_right = d.copy(), d * 1.1  # a gentle left arc
    d_left[0] = d_right[0] = 0.0
    x, y, yaw = integrate(d_left, d_right, NOMINAL.wheel_separation)
    dt = np.concatenate([[0.0], np.full(steps - 1, 0.02)])
    # the reference: the same path, 10 mm to the side and 0.02 rad turned; so the speeds agree
    segment = Segment(d_left, d_right, x + 0.0, y + 0.01, yaw + 0.02, dt)
    figures = residual_figures([segment], NOMINAL, NOMINAL)
    assert (figures.steps, figures.x_m, figures.y_m, figures.yaw_rad) == (steps, 0.0, pytest.approx(0.01), pytest.approx(0.02))
    assert figures.path_m == pytest.approx(float(np.sum(d_left + d_right)) / 2)
    assert figures.v_mps == pytest.approx(0.0, abs=1e-4) and figures.w_radps == pytest.approx(0.0, abs=1e-4)  # chord and arc
    faster = Segment(d_left, d_right, x * 1.1, y * 1.1, yaw, dt)  # the reference went 10 % further in the same time
    assert residual_figures([faster], NOMINAL, NOMINAL).v_mps == pytest.approx(0.1 * 0.0021 / 0.02, rel=2e-2)
    assert math.isnan(residual_figures([Segment(d_left, d_right, x, y, yaw)], NOMINAL, NOMINAL).v_mps)  # no time steps


def write_squares(path: Path) -> None:
    """A recording of a 1 m square: nominal impulses, and the truth a robot with a 1.5 % larger left wheel and a
    0.515 m wheelbase drew with them, 4 mm of lateral wobble on it (what the residuals must show)."""
    from blackmetal.bench.synth import square_legs, synth_log
    from blackmetal.recording.writer import McapRecording
    from blackmetal.schemas import encode, make_pose

    keys = Keys()
    rec = McapRecording(path, keys)
    start = 1_795_000_000.0
    for clockwise in (False,):
        log = synth_log(square_legs(side=1.0, clockwise=clockwise), seed=2, start=start)
        left, right = Encoders().to_speeds(log.left.astype(float), log.right.astype(float))
        dt = np.diff(log.stamp, prepend=log.stamp[0])
        x, y, yaw = integrate(left * dt * 1.015, right * dt, 0.515)
        wobble = 0.004 * np.sin(np.arange(len(x)) / 15.0)
        x, y = x - wobble * np.sin(yaw), y + wobble * np.cos(yaw)
        for seq, stamp, il, ir in zip(log.seq, log.stamp, log.left, log.right, strict=True):
            rec.write(keys.impulses, b'{"seq":%d,"stamp":%r,"left":%d,"right":%d}' % (seq, float(stamp), il, ir), int(stamp * 1e9))
        for i in range(0, len(x), 2):
            stamp = float(log.stamp[i])
            rec.write(keys.sim_truth, encode(make_pose(stamp, float(x[i]), float(y[i]), float(yaw[i]))), int(stamp * 1e9))
        start = float(log.stamp[-1]) + 1.0
    rec.close()


@pytest.mark.slow
def test_calibrate_writes_residuals_every_service_takes_and_ros2_makes_the_covariance_of_them(tmp_path: Path, codec: RosCodec) -> None:
    recording = tmp_path / "squares.mcap"
    write_squares(recording)
    out = tmp_path / "calibration.toml"
    made = cli("calibrate", str(recording), "-o", str(out))
    assert made.returncode == 0, made.stdout + made.stderr
    assert "residuals after the fit over" in made.stdout
    calibration = read_calibration(str(out))
    r = calibration.residuals
    assert r is not None and r.steps > 100 and r.path_m > 4.0, made.stdout
    assert 0.001 < math.hypot(r.x_m, r.y_m) < 0.01, made.stdout  # the wobble (4 mm amplitude), not the constants' error
    assert calibration.wheel_separation == pytest.approx(0.515, rel=1e-2)
    assert all(math.isfinite(v) and v >= 0 for v in (r.x_m, r.y_m, r.yaw_rad, r.v_mps, r.w_radps))
    assert "blackmetal calibrate" in calibration.note
    # the gateway and the odometry still take it as their settings (the residuals are comments)
    assert load_settings(GatewaySettings, {}, settings_file=str(out)).wheel_separation == calibration.wheel_separation
    assert load_settings(OdometrySettings, {}, settings_file=str(out)).impulses_left == calibration.impulses_left
    # the ROS 2 adapter: the file's constants, and /odom's covariance of its residuals
    settings = load_settings(Ros2Settings, {"calibration": str(out)})
    options = settings.options({"cmd_vel": "c", "estop": "e"})
    assert options.encoders == Encoders(calibration.impulses_left, calibration.impulses_right)
    assert options.pose_covariance[0] == max(r.x_m**2, MIN_VARIANCE) and options.pose_covariance[35] == max(r.yaw_rad**2, MIN_VARIANCE)
    assert options.twist_covariance[0] == max(r.v_mps**2, MIN_VARIANCE) and options.twist_covariance[35] == max(r.w_radps**2, MIN_VARIANCE)
    assert options.pose_covariance[14] == 0.001  # z: the configured diagonal
    assert options.robot is not None and f'0 {calibration.wheel_separation / 2:.6g} 0"' in options.robot.urdf
    # /diagnostics says which calibration is in use and where the covariance comes from
    out_ros = Recorder()
    core = Ros2Core(options, Keys(), out_ros, codec)
    core.tick(0.0)
    status = read_diagnostics(next(c for t, c in out_ros.ros_out if t == "diagnostics"))["blackmetal: ROS 2 adapter"]
    assert status["values"]["calibration"].startswith(str(out)) and str(out) in status["message"]
    assert status["values"]["odometry covariance"].startswith(f"x, y, yaw, v, w from the residuals of {out}")
    # a calibration without residuals (UMBmark, or an older file): fixed diagonals, and the reason
    plain = tmp_path / "umbmark.toml"
    plain.write_text("\n".join(line for line in out.read_text().splitlines() if not line.startswith(model.RESIDUAL_LINE)) + "\n")
    unmeasured = load_settings(Ros2Settings, {"calibration": str(plain)}).options({"cmd_vel": "c", "estop": "e"})
    assert unmeasured.pose_covariance[0] == 0.001 and "holds no residuals" in unmeasured.covariance


def test_a_broken_calibration_file_is_one_sentence(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    for text, message in (
        ("wheel_separation = 0.5\n", "has no positive impulses_left"),
        ("wheel_separation = 0.5\nimpulses_left = 1.0\nimpulses_right = 1.0\n# residuals.x_m = 1\n", "lacks the residual lines"),
        ("x = [", "is not valid TOML"),
    ):
        bad.write_text(text)
        with pytest.raises(ConfigError, match=message):
            Ros2Settings(calibration=str(bad)).check()
    with pytest.raises(ConfigError, match="cannot read the calibration file"):
        Ros2Settings(calibration=str(tmp_path / "none.toml")).check()


def test_up_passes_the_distro_and_a_calibration_with_residuals_to_the_adapter(tmp_path: Path) -> None:
    from blackmetal.tools.up import build_parser, ros2_extra

    calibration = tmp_path / "calibration.toml"
    calibration.write_text("# note\n# residuals.x_m = 0.001\nwheel_separation = 0.5\n")
    args = build_parser().parse_args(["--ros2", "--distro", "humble,jazzy", "--settings", str(calibration)])
    assert ros2_extra(args) == ["--distro", "humble,jazzy", "--calibration", str(calibration)]
    plain = tmp_path / "plain.toml"
    plain.write_text("poll_hz = 50\n")
    assert ros2_extra(build_parser().parse_args(["--ros2", "--settings", str(plain)])) == []
    assert json.dumps(ros2_extra(build_parser().parse_args(["--ros2"]))) == "[]"
