"""``blackmetal urdf``: print the robot's URDF, for users who run their own robot_state_publisher.

The URDF comes from the robot model (``base_footprint``, ``base_link``, the
two continuous wheel joints named as ``blackmetal ros2`` names them in
``/joint_states``, a rear caster), with the wheel separation and radius the
gateway and the adapter use unless given here: pass the calibrated wheel
separation after ``blackmetal calibrate``, or its file with ``--calibration``.
``blackmetal ros2`` publishes the same URDF on ``/robot_description`` (and
its transforms), so RViz needs no robot_state_publisher; this command is for
those who run their own (then give the adapter ``--no-robot-model``). For
example::

    blackmetal urdf --calibration calibration.toml > blackmetal.urdf
    ros2 run robot_state_publisher robot_state_publisher --ros-args -p robot_description:="$(cat blackmetal.urdf)"
"""

from __future__ import annotations

import argparse
import sys

from blackmetal import robot_model as model

from .client import tool


@tool("urdf")
def run(args: argparse.Namespace) -> int:
    separation = model.read_calibration(args.calibration).wheel_separation if args.calibration else args.wheel_separation
    body = model.Body(wheel_separation=separation, wheel_radius=args.wheel_radius)
    sys.stdout.write(
        model.urdf(body, left_joint=args.left_joint, right_joint=args.right_joint, frame_prefix=args.frame_prefix, name=args.name)
    )
    return 0


def build_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--wheel-separation", type=float, default=model.WHEEL_SEPARATION, metavar="M", help=f"m (default {model.WHEEL_SEPARATION:g})"
    )
    parser.add_argument(
        "--calibration", metavar="FILE", help="take the wheel separation from this file of blackmetal calibrate -o (default none)"
    )
    parser.add_argument("--wheel-radius", type=float, default=model.WHEEL_RADIUS, metavar="M", help=f"m (default {model.WHEEL_RADIUS:g})")
    parser.add_argument("--left-joint", default="left_wheel_joint", metavar="NAME", help="as in /joint_states (default left_wheel_joint)")
    parser.add_argument("--right-joint", default="right_wheel_joint", metavar="NAME", help="(default right_wheel_joint)")
    parser.add_argument("--frame-prefix", default="", metavar="PREFIX", help="before every link, e.g. r2/ in a fleet (default none)")
    parser.add_argument("--name", default="blackmetal", help="the robot's name in the URDF (default blackmetal)")
