"""``blackmetal ros2`` settings (:mod:`blackmetal.ros2.settings`): checks in one sentence, covariances, the robot model."""

from __future__ import annotations

import pytest

from blackmetal.robot_model import Calibration, Residuals
from blackmetal.ros2.naming import Distro
from blackmetal.ros2.settings import MIN_VARIANCE, ROOT_LINK, Ros2Settings, diagonal_matrix
from blackmetal.schemas import ConfigError

KEYS = {"cmd_vel": "c", "estop": "e"}


def test_a_diagonal_is_the_row_major_six_by_six_matrix() -> None:
    matrix = diagonal_matrix("1,2,3,4,5,6", "x")
    assert len(matrix) == 36 and [matrix[7 * i] for i in range(6)] == [1, 2, 3, 4, 5, 6]
    assert sum(matrix) == 21
    for bad in ("1,2,3", "a,b,c,d,e,f", "1,2,3,4,5,-6", "1,2,3,4,5,nan"):
        with pytest.raises(ConfigError, match="pose_covariance_diagonal must be six comma-separated"):
            diagonal_matrix(bad, "pose_covariance_diagonal")


@pytest.mark.parametrize(
    ("changes", "sentence"),
    [
        ({"base_frame": "base_link"}, "--base-frame base_link: the robot model's root link is base_footprint"),
        ({"domain_id": 233}, "ROS domain id must be 0..232, got 233"),
        ({"node_name": "9lives"}, "node name '9lives' is not a valid ROS name"),
        ({"odom_frame": ""}, "odom_frame must not be empty"),
        ({"source": "a/b"}, "source 'a/b' must be letters, digits"),
        ({"distro": "foxy"}, "--distro 'foxy' is not a ROS 2 distro"),
        ({"rmf_battery": 1.5}, "rmf_battery is a charge 0..1"),
        ({"rmf": True, "flavor": "bridge", "namespace": "robot"}, "--rmf with the bridge flavour in namespace 'robot' would serve"),
        ({"rmf_battery": float("nan")}, "rmf_battery is a charge 0..1"),
        ({"rmf": True, "rmf_name": "a/*"}, "rmf_name 'a/*' cannot head free_fleet's keys"),
    ],
)
def test_a_setting_the_node_cannot_use_is_one_sentence(changes: dict[str, object], sentence: str) -> None:
    settings = Ros2Settings(**changes)  # type: ignore[arg-type]
    with pytest.raises(ConfigError) as error:
        settings.check()
    assert str(error.value).startswith(sentence)


def test_another_base_frame_is_fine_without_the_robot_model() -> None:
    Ros2Settings(base_frame="base_link", robot_model=False).check()
    assert Ros2Settings().base_frame == ROOT_LINK


def test_the_distro_of_a_sourced_ros_is_named_when_it_is_wrong(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ROS_DISTRO", "iron")
    with pytest.raises(ConfigError, match=r"^ROS_DISTRO 'iron'"):
        Ros2Settings(distro="iron").distros()
    assert Ros2Settings(distro="humble, jazzy").distros() == (Distro.HUMBLE, Distro.JAZZY)


def test_the_covariance_comes_from_a_calibrations_residuals_where_it_measured_them() -> None:
    settings = Ros2Settings()
    pose, twist, why = settings.covariances(None)
    assert pose[0] == 0.001 and pose[35] == 0.01 and why.startswith("fixed diagonals")
    residuals = Residuals(steps=10, path_m=12.0, x_m=0.02, y_m=0.0, yaw_rad=0.01, v_mps=0.03, w_radps=0.04)
    calibration = Calibration("cal.txt", "note", 0.5, 1000.0, 1000.0, residuals)
    pose, twist, why = settings.covariances(calibration)
    assert pose[0] == pytest.approx(4e-4) and pose[7] == MIN_VARIANCE and pose[35] == pytest.approx(1e-4)
    assert pose[14] == 0.001, "z is not measured: the configured diagonal stays"
    assert twist[0] == pytest.approx(9e-4) and twist[35] == pytest.approx(16e-4)
    assert why.startswith("x, y, yaw, v, w from the residuals of cal.txt over 12.0 m (rms x 20.0 mm")
    _, _, why = settings.covariances(Calibration("umb.txt", "note", 0.5, 1000.0, 1000.0, None))
    assert why.endswith("umb.txt holds no residuals (a UMBmark calibration measures none)")


def test_a_fleet_nodes_options_prefix_every_frame_and_link() -> None:
    options = Ros2Settings(namespace="r3").options(KEYS, frame_prefix="r3/", distro=Distro.HUMBLE)
    assert (options.frames.odom, options.frames.base) == ("r3/odom", "r3/base_footprint")
    assert options.node == "/r3/blackmetal" and options.distro == "humble"
    robot = options.robot
    assert robot is not None and 'link name="r3/base_footprint"' in robot.urdf
    assert [w.child for w in robot.wheels] == ["r3/left_wheel", "r3/right_wheel"]
    assert all(t.parent.startswith("r3/") and t.child.startswith("r3/") for t in robot.fixed)
    assert Ros2Settings(robot_model=False).options(KEYS).robot is None
    assert Ros2Settings(flavor="bridge").options(KEYS).distro == "any (zenoh-bridge-ros2dds)"


def test_free_fleets_robot_name_and_battery() -> None:
    assert Ros2Settings(prefix="fleet/r3").rmf_robot() == "r3" and Ros2Settings().rmf_robot() == "robot"
    assert Ros2Settings(prefix="fleet/r3", rmf_name="tinyRobot1").rmf_robot() == "tinyRobot1"
    options = Ros2Settings(rmf=True, rmf_battery=0.75).options({}, distro=Distro.HUMBLE)
    assert (options.rmf_name, options.rmf_battery, options.nav_layout) == ("robot", 0.75, "humble")
    assert (options.rmf_frames.odom, options.rmf_frames.base) == ("odom", "base_footprint")  # never prefixed
    off = Ros2Settings().options({}, frame_prefix="r1/", distro=Distro.ROLLING)
    assert (off.rmf_name, off.rmf_battery, off.nav_layout, off.frames.odom) == ("", None, "rolling", "r1/odom")
