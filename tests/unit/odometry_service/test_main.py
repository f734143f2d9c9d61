"""``blackmetal odometry``: its options, and the whole chain with a simulated robot and a gateway."""

from __future__ import annotations

import json
import math
import signal
import time

import pytest
import zenoh
from helpers import Child, client_config, free_port, start_robot, wait_for

from blackmetal.odometry_service.main import build_parser
from blackmetal.schemas import Pose, decode


def test_the_options_are_the_pipelines_and_the_fleet() -> None:
    args = build_parser().parse_args(["--filter-alpha", "0.5", "--no-mirror-right", "--fleet", "robots.toml"])
    assert (args.filter_alpha, args.mirror_right, args.fleet) == (0.5, False, "robots.toml")


@pytest.mark.integration
def test_drive_the_simulator_and_the_pose_follows_the_truth(children: list[Child]) -> None:
    zport = free_port()
    _, _, odometry = start_robot(children, zport, gateway_args=("--cmd-timeout", "1.0", "--poll-hz", "50"))
    with zenoh.open(client_config(zport)) as session:
        poses: list[Pose] = []
        session.declare_subscriber("robot/pose", lambda s: poses.append(decode(Pose, s.payload.to_bytes())))
        wait_for(lambda: len(poses) > 10, what="poses from the odometry service")

        def get(key: str, payload: bytes | None = None) -> Pose:
            replies = [r for r in session.get(key, payload=payload, timeout=5) if r.ok is not None]
            assert replies, f"no answer on {key}"
            return decode(Pose, replies[0].ok.payload.to_bytes())

        def drive(v: float, w: float, seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:  # a teleop-like stream at 10 Hz
                session.put("robot/cmd_vel", json.dumps({"linear": {"x": v}, "angular": {"z": w}}))
                time.sleep(0.1)

        def stopped() -> bool:
            return abs(get("robot/sim/truth").v) < 1e-9 and abs(get("robot/pose").v) < 1e-9

        get("robot/odometry/reset")
        start_truth = get("robot/sim/truth")
        for v, w, seconds in [(0.3, 0.0, 3.0), (0.0, 0.8, 2.0), (0.25, 0.4, 3.0), (0.0, 0.0, 0.5), (0.2, -0.6, 2.5)]:
            drive(v, w, seconds)
        wait_for(stopped, timeout=10, what="the robot and the odometry to stand still")
        truth = get("robot/sim/truth")
        pose = get("robot/pose")
        # the truth started where it was at the reset; odometry started at zero
        dx, dy = truth.x - start_truth.x, truth.y - start_truth.y
        c, s = math.cos(-start_truth.yaw), math.sin(-start_truth.yaw)
        rel_x, rel_y = c * dx - s * dy, s * dx + c * dy
        rel_yaw = math.remainder(truth.yaw - start_truth.yaw, math.tau)
        travelled = 0.3 * 3 + 0.25 * 3 + 0.2 * 2.5
        assert math.hypot(rel_x, rel_y) > 0.5, "the robot did not move"
        print(
            f"odometry vs truth: {1000 * math.hypot(pose.x - rel_x, pose.y - rel_y):.1f} mm, {1000 * abs(math.remainder(pose.yaw - rel_yaw, math.tau)):.1f} mrad"
        )
        assert math.hypot(pose.x - rel_x, pose.y - rel_y) < 0.02, (pose, rel_x, rel_y, travelled)
        assert abs(math.remainder(pose.yaw - rel_yaw, math.tau)) < 0.03
        alive = [str(r.ok.key_expr) for r in session.liveliness().get("robot/alive/*", timeout=5) if r.ok is not None]
        assert "robot/alive/odometry" in alive and "robot/alive/gateway" in alive
    start = time.monotonic()
    assert odometry.stop(signal.SIGTERM) == 0
    assert time.monotonic() - start < 2.0
