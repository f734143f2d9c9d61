"""The robot's URDF (``blackmetal urdf``): accepted by urdfdom's own parser, and true to the robot model and /joint_states."""

from __future__ import annotations

import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from blackmetal import robot_model as model
from blackmetal.ros2.settings import Ros2Settings


def check_urdf() -> str:
    """urdfdom's check_urdf (the cmeel-urdfdom wheel of the test extra), beside this interpreter or on PATH."""
    found = Path(sys.executable).with_name("check_urdf")
    path = str(found) if found.exists() else shutil.which("check_urdf")
    if path is None:
        pytest.skip("urdfdom's check_urdf is not installed: pip install cmeel-urdfdom (in the test extra)")
    return path


def blackmetal_urdf(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "blackmetal", "urdf", *args], capture_output=True, text=True, timeout=60)


def test_urdfdom_accepts_the_urdf_and_it_has_the_robot_models_wheels(tmp_path: Path) -> None:
    made = blackmetal_urdf()
    assert made.returncode == 0, made.stderr
    path = tmp_path / "blackmetal.urdf"
    path.write_text(made.stdout)
    checked = subprocess.run([check_urdf(), str(path)], capture_output=True, text=True, timeout=60)
    assert checked.returncode == 0 and "Successfully Parsed XML" in checked.stdout, checked.stdout + checked.stderr
    assert "root Link: base_footprint" in checked.stdout
    robot = ET.fromstring(made.stdout)
    joints = {j.get("name"): j for j in robot.iter("joint")}
    ros2 = Ros2Settings()
    wheels = {name: joints[name] for name in (ros2.left_joint, ros2.right_joint)}  # named as /joint_states names them
    assert all(j.get("type") == "continuous" and j.find("axis").get("xyz") == "0 1 0" for j in wheels.values())  # type: ignore[union-attr]
    ys = [float(j.find("origin").get("xyz").split()[1]) for j in wheels.values()]  # type: ignore[union-attr]
    assert ys == [model.WHEEL_SEPARATION / 2, -model.WHEEL_SEPARATION / 2]
    radii = {float(c.get("radius")) for c in robot.iter("cylinder")}  # type: ignore[arg-type]
    assert radii == {model.WHEEL_RADIUS}


def test_a_fleet_robot_has_its_frames_prefixed_and_a_calibrated_separation(tmp_path: Path) -> None:
    made = blackmetal_urdf("--frame-prefix", "r2/", "--wheel-separation", "0.47")
    path = tmp_path / "r2.urdf"
    path.write_text(made.stdout)
    checked = subprocess.run([check_urdf(), str(path)], capture_output=True, text=True, timeout=60)
    assert checked.returncode == 0 and "root Link: r2/base_footprint" in checked.stdout, checked.stdout
    robot = ET.fromstring(made.stdout)
    assert all((link.get("name") or "").startswith("r2/") for link in robot.iter("link"))
    assert robot.find("joint[@name='left_wheel_joint']/origin").get("xyz") == "0 0.235 0"  # type: ignore[union-attr]


def test_an_impossible_dimension_is_one_sentence() -> None:
    bad = blackmetal_urdf("--wheel-radius", "-1")
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "wheel_radius must be a positive length" in bad.stderr


def test_the_calibration_in_use_gives_the_separation(tmp_path: Path) -> None:
    calibration = tmp_path / "calibration.toml"
    calibration.write_text("# blackmetal calibrate\nwheel_separation = 0.512\nimpulses_left = 1010.0\nimpulses_right = 1050.0\n")
    made = blackmetal_urdf("--calibration", str(calibration))
    assert made.returncode == 0, made.stderr
    assert ET.fromstring(made.stdout).find("joint[@name='right_wheel_joint']/origin").get("xyz") == "0 -0.256 0"  # type: ignore[union-attr]
    missing = blackmetal_urdf("--calibration", str(tmp_path / "none.toml"))
    assert missing.returncode == 2 and missing.stderr.count("\n") == 1 and "cannot read the calibration file" in missing.stderr
