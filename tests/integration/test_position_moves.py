"""A position move through a real gateway on Zenoh, run by ``blackmetal sim``'s own SET_LR_WHEEL_POSITION on loopback."""

from __future__ import annotations

import json
import math

import pytest
import zenoh
from helpers import Child, client_config, wait_for

from blackmetal.schemas import MoveState, WheelMoveReply, WheelPosition, decode

from .test_gateway_zenoh import Rig, health, truth

pytestmark = pytest.mark.integration


def move(session: zenoh.Session, **fields: object) -> WheelMoveReply:
    replies = [r.ok.payload.to_bytes() for r in session.get("robot/wheels/move", payload=json.dumps(fields).encode(), timeout=5) if r.ok]
    assert len(replies) == 1
    return decode(WheelMoveReply, replies[0])


def test_a_move_and_a_turn_run_on_the_robot_and_an_estop_ends_the_next(children: list[Child]) -> None:
    rig = Rig(children, "--position-moves")
    with zenoh.open(client_config(rig.zport)) as session:
        wait_for(lambda: (h := health(session)) is not None and h.control.state == "connected", what="a connected gateway")
        published: list[WheelPosition] = []
        session.declare_subscriber("robot/wheels/position", lambda s: published.append(decode(WheelPosition, s.payload.to_bytes())))
        start = truth(session)
        reply = move(session, left=0.6, right=0.6)
        assert reply.accepted, reply.reason
        wait_for(lambda: any(p.move_id == reply.move_id and p.state is MoveState.DONE for p in published), timeout=10, what="the move done")
        pose = truth(session)
        assert math.hypot(pose.x - start.x, pose.y - start.y) == pytest.approx(0.6, abs=0.005)
        quarter = math.pi / 2 * 0.25
        turn = move(session, left=-quarter, right=quarter)
        assert turn.accepted, turn.reason
        wait_for(lambda: any(p.move_id == turn.move_id and p.state is MoveState.DONE for p in published), timeout=10, what="the turn done")
        turned = math.remainder(truth(session).yaw - pose.yaw, 2 * math.pi)
        assert math.degrees(turned) == pytest.approx(90.0, abs=0.5)
        long = move(session, left=3.0, right=3.0)
        assert long.accepted
        wait_for(lambda: any(p.move_id == long.move_id for p in published), what="the long move under way")
        session.put("robot/estop", b'{"engaged": true}')
        wait_for(lambda: any(p.move_id == long.move_id and p.state is MoveState.ENDED for p in published), what="the move ended")
        assert [p.reason for p in published if p.state is MoveState.ENDED] == ["the e-stop is engaged"]
        stopped = wait_for(lambda: (t := truth(session)).v == 0.0 and t.w == 0.0 and t, what="the robot standing")
        assert math.hypot(stopped.x - pose.x, stopped.y - pose.y) < 3.0  # stopped short of the long move's end
        refused = move(session, left=0.1, right=0.1)
        assert not refused.accepted and "emergency stop is engaged" in refused.reason


def test_goto_move_and_turn_are_run_by_the_robot_where_the_gateway_runs_position_moves(children: list[Child]) -> None:
    """``blackmetal goto --move / --turn`` through ``blackmetal nav``: the gateway's wheels/move carries them out (no
    velocity command from nav), the goal succeeds when the wheels stand at their target."""
    import subprocess
    import sys

    from helpers import zenoh_connect_args

    rig = Rig(children, "--position-moves")
    for service in ("odometry", "nav"):
        child = Child(["-m", "blackmetal", service, *zenoh_connect_args(rig.zport)])
        children.append(child)
        child.ready()
    with zenoh.open(client_config(rig.zport)) as session:
        wait_for(lambda: (h := health(session)) is not None and h.control.state == "connected", what="a connected gateway")
        twists: list[bytes] = []
        session.declare_subscriber("robot/cmd_vel/nav", lambda s: twists.append(s.payload.to_bytes()))
        moves: list[WheelPosition] = []
        session.declare_subscriber("robot/wheels/position", lambda s: moves.append(decode(WheelPosition, s.payload.to_bytes())))
        start = truth(session)
        goto = [sys.executable, "-m", "blackmetal", "goto", "-e", f"tcp/127.0.0.1:{rig.zport}", "--no-multicast-scouting", "--wait", "20"]
        done = subprocess.run([*goto, "--move", "0.4"], capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stdout + done.stderr
        moved = truth(session)
        assert math.hypot(moved.x - start.x, moved.y - start.y) == pytest.approx(0.4, abs=0.01)
        assert moves and moves[-1].state is MoveState.DONE and twists == [], "the robot's position control ran it, not nav's twists"
        done = subprocess.run([*goto, "--turn", "-90"], capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stdout + done.stderr
        turned = math.remainder(truth(session).yaw - moved.yaw, 2 * math.pi)
        assert math.degrees(turned) == pytest.approx(-90.0, abs=1.0)
        assert twists == []
