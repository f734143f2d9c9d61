"""One wheel order through every layer: a left-only and a right-only command move exactly that wheel.

Twist -> gateway -> wire bytes -> simulator -> impulses -> odometry, with
real processes and Zenoh: a command that turns only the left wheel must
reach the robot as ``LeftWheelSpeed`` (and ``RightWheelSpeed`` 0), turn the
simulated robot clockwise, come back as left impulses only, and turn the
odometry's pose clockwise too; the right wheel the mirror image. One
positional slip anywhere would swap the wheels on a real robot.
"""

from __future__ import annotations

import json
import math
import time

import pytest
import zenoh
from helpers import Child, client_config, free_port, start_robot, wait_for

from blackmetal import wire
from blackmetal.gateway.core import GatewayCore
from blackmetal.gateway.settings import GatewaySettings
from blackmetal.robot_model import WHEEL_SEPARATION, twist_to_wheels
from blackmetal.schemas import Pose, WheelImpulses, decode
from blackmetal.sim.physics import RobotParams, SimRobot
from blackmetal.wire import CommandCode, RequestDecoder

#: Forward speed and turn rate that drive one wheel at 0.2 m/s and hold the other still.
V = 0.1
W = 2 * V / WHEEL_SEPARATION
LEFT_ONLY = (V, -W)  # turning right, clockwise, on the left wheel
RIGHT_ONLY = (V, W)  # turning left, counter-clockwise, on the right wheel


def test_one_wheel_commands_reach_the_wire_and_the_robot_as_that_wheel() -> None:
    """The pure layers on a fake clock, down to the bytes on the wire."""
    for (v, w), moving in ((LEFT_ONLY, "left"), (RIGHT_ONLY, "right")):
        wheels, _ = twist_to_wheels(v, w, WHEEL_SEPARATION, 0.8)
        assert getattr(wheels, moving) == pytest.approx(0.2) and getattr(wheels, "right" if moving == "left" else "left") == 0.0
        conn = GatewayCore(GatewaySettings(cmd_timeout=0.0), 0.0, wallclock=lambda: 0.0)
        robot = SimRobot(RobotParams(), now=0.0)
        conn.link_up("control", 0.0)
        conn.on_cmd_vel("default", json.dumps({"linear": {"x": v}, "angular": {"z": w}}).encode(), 0.01)
        data = conn.take_outgoing("control")
        frames = [json.loads(frame) for frame in data.replace(b"}{", b"}\n{").splitlines()]  # the exact bytes for the robot
        (frame,) = [
            f for f in frames if "LeftWheelSpeed" in f and f != {"UserID": 1, "Command": 3, "RightWheelSpeed": 0, "LeftWheelSpeed": 0}
        ]
        still = "Right" if moving == "left" else "Left"
        assert frame[f"{moving.title()}WheelSpeed"] == pytest.approx(0.2) and frame[f"{still}WheelSpeed"] == 0.0
        velocity = [
            r for r in RequestDecoder().feed(data) if isinstance(r, wire.Request) and r.command is CommandCode.SET_LR_WHEEL_VELOCITY
        ]
        for request in velocity:
            robot.handle(request, 0.01)
        robot.advance(1.0)
        assert (robot.speed_left, robot.speed_right) == ((0.2, 0.0) if moving == "left" else (0.0, 0.2))
        assert robot.yaw < 0 if moving == "left" else robot.yaw > 0


@pytest.mark.integration
def test_one_wheel_commands_move_that_wheel_through_every_process(children: list[Child]) -> None:
    zport = free_port()
    start_robot(children, zport, gateway_args=("--cmd-timeout", "1.0", "--poll-hz", "50"))
    with zenoh.open(client_config(zport)) as session:
        impulses: list[WheelImpulses] = []
        session.declare_subscriber("robot/wheels/impulses", lambda s: impulses.append(decode(WheelImpulses, s.payload.to_bytes())))

        def get(key: str) -> Pose:
            replies = [r for r in session.get(key, timeout=5) if r.ok is not None]
            assert replies, f"no answer on {key}"
            return decode(Pose, replies[0].ok.payload.to_bytes())

        def standing() -> bool:
            return abs(get("robot/sim/truth").w) < 1e-9 and abs(get("robot/pose").w) < 1e-9

        wait_for(lambda: len(impulses) > 5, what="impulses from the gateway")
        for (v, w), moving in ((LEFT_ONLY, "left"), (RIGHT_ONLY, "right")):
            wait_for(standing, what="the robot to stand still")
            truth_before, pose_before = get("robot/sim/truth"), get("robot/pose")
            impulses.clear()
            end = time.monotonic() + 1.5
            while time.monotonic() < end:  # a teleop-like stream at 10 Hz
                session.put("robot/cmd_vel", json.dumps({"linear": {"x": v}, "angular": {"z": w}}))
                time.sleep(0.1)
            session.put("robot/cmd_vel", json.dumps({"linear": {"x": 0.0}, "angular": {"z": 0.0}}))
            wait_for(standing, what="the robot to stop")
            truth_turn = math.remainder(get("robot/sim/truth").yaw - truth_before.yaw, math.tau)
            pose_turn = math.remainder(get("robot/pose").yaw - pose_before.yaw, math.tau)
            lefts = [m.left for m in impulses]
            rights = [m.right for m in impulses]
            if moving == "left":
                assert max(lefts) > 150 and rights == [0] * len(rights), (lefts, rights)
                assert truth_turn < -0.3 and pose_turn < -0.3, (truth_turn, pose_turn)  # clockwise
            else:
                assert min(rights) < -150 and lefts == [0] * len(lefts), (lefts, rights)  # the right encoder is mirrored
                assert truth_turn > 0.3 and pose_turn > 0.3, (truth_turn, pose_turn)  # counter-clockwise
            assert pose_turn == pytest.approx(truth_turn, abs=0.05)
