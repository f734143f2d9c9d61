"""NavCore running a relative move by the robot's own position control, against the gateway's core and the simulator's
physics on one fake clock: the move's request, its progress, its end; a cancel and a refusal."""

from __future__ import annotations

import math
from typing import Any

import pytest

from blackmetal.nav.core import NavCore
from blackmetal.nav.params import NavParams
from blackmetal.schemas import GoalState, Keys, MapPose, NavFeedback, NavGoalReply, Twist, WheelMove, WheelPosition, encode, make_pose
from unit.gateway.test_core import WALL0
from unit.gateway.test_core import Bench as GatewayBench

KEYS = Keys("robot")


class Rig:
    """The nav core, its outputs carried to the gateway's core (twists, moves) and back (replies, wheel positions)."""

    def __init__(self, **gateway: Any) -> None:
        self.gateway = GatewayBench(**gateway)
        self.gateway.connect()
        self.out: list[Any] = []
        self.nav = NavCore(NavParams(), KEYS, self.out.append, map_pose=MapPose(0.0, 0.0, 0.0, 0.0), wallclock=lambda: WALL0 + self.now)
        self.nav.tick(self.now)
        for role in ("gateway", "odometry"):
            self.nav.on_alive(role, True, self.now)
        self.nav.on_gateway_params(encode(self.gateway.conn.params_now()), self.now)
        self.nav.on_health(encode(self.gateway.conn.health(self.now)), self.now)
        self._sent = 0

    @property
    def now(self) -> float:
        return self.gateway.t

    def carry(self) -> None:
        """The nav core's new outputs to the gateway: a twist on cmd_vel/nav, a move as a get on wheels/move."""
        while self._sent < len(self.out):
            message = self.out[self._sent]
            self._sent += 1
            if isinstance(message, Twist):
                self.gateway.conn.on_cmd_vel("nav", encode(message), self.now)
            elif isinstance(message, WheelMove):
                self.nav.on_wheel_move_reply(encode(self.gateway.conn.on_wheel_move(encode(message), self.now)), self.now)
        self.gateway.settle()

    def run(self, seconds: float) -> None:
        end = self.now + seconds
        while self.now < end:
            self.gateway.run(0.02)
            robot = self.gateway.robot
            x, y, yaw = robot.x, robot.y, robot.yaw
            self.nav.on_pose(encode(make_pose(WALL0 + self.now, x, y, yaw)), self.now)
            for event in self.gateway.events:
                if isinstance(event, WheelPosition):
                    self.nav.on_wheel_position(encode(event), self.now)
            self.gateway.events.clear()
            self.nav.tick(self.now)
            self.carry()

    def move(self, **fields: float) -> NavGoalReply:
        reply = self.nav.on_move(encode(fields) if False else __import__("json").dumps(fields).encode(), self.now)
        self.carry()
        return reply

    def feedback(self) -> list[NavFeedback]:
        return [m for m in self.out if isinstance(m, NavFeedback)]


def test_a_move_goes_to_the_robots_position_control_where_the_gateway_runs_them() -> None:
    rig = Rig(position_moves=True)
    rig.run(0.2)
    reply = rig.move(distance=0.5)
    assert reply.accepted
    moves = [m for m in rig.out if isinstance(m, WheelMove)]
    assert len(moves) == 1 and moves[0].left == moves[0].right == pytest.approx(0.5) and moves[0].move_id == reply.goal_id
    assert not [m for m in rig.out if isinstance(m, Twist)], "the controller stands aside: a twist would end the move"
    rig.run(4.0)
    last = rig.feedback()[-1]
    assert last.state is GoalState.SUCCEEDED, last
    assert rig.gateway.robot.x == pytest.approx(0.5, abs=0.005) and abs(rig.gateway.robot.y) < 0.005
    running = [f for f in rig.feedback() if not f.state.done]
    assert running and running[0].distance_remaining == pytest.approx(0.5, abs=0.02)
    assert min(f.distance_remaining for f in running) < 0.1


def test_a_turn_by_the_robot_ends_at_its_angle() -> None:
    rig = Rig(position_moves=True)
    rig.run(0.2)
    assert rig.move(angle=math.pi / 2).accepted
    rig.run(3.0)
    assert rig.feedback()[-1].state is GoalState.SUCCEEDED
    assert math.degrees(rig.gateway.robot.yaw) == pytest.approx(90.0, abs=0.5)


def test_a_cancel_ends_the_robots_move_with_one_zero_twist_and_it_stands() -> None:
    rig = Rig(position_moves=True)
    rig.run(0.2)
    reply = rig.move(distance=2.0)
    rig.run(1.0)
    canceled = rig.nav.on_cancel(None, rig.now)
    rig.carry()
    assert canceled.canceled == [reply.goal_id]
    assert [m for m in rig.out if isinstance(m, Twist)] == [Twist()]
    rig.run(0.5)
    x = rig.gateway.robot.x
    rig.run(1.0)
    assert rig.gateway.robot.x == pytest.approx(x, abs=1e-6) and 0.1 < x < 1.0
    assert rig.feedback()[-1].state is GoalState.CANCELED


def test_without_position_moves_a_move_is_the_controllers() -> None:
    rig = Rig()
    rig.run(0.2)
    assert rig.move(distance=0.3).accepted
    assert not [m for m in rig.out if isinstance(m, WheelMove)]
    rig.run(4.0)
    assert rig.feedback()[-1].state is GoalState.SUCCEEDED
    assert rig.gateway.robot.x == pytest.approx(0.3, abs=0.01)


def test_a_move_the_gateway_refuses_is_aborted_with_its_reason() -> None:
    rig = Rig(position_moves=True)
    rig.run(0.2)
    rig.gateway.conn.on_cmd_vel("teleop", b'{"linear": {"x": 0.1}}', rig.now)  # a higher source drives: the move is refused
    rig.gateway.settle()
    reply = rig.move(distance=0.5)
    assert reply.accepted  # the navigation took it; the gateway's answer ends it
    last = rig.feedback()[-1]
    assert last.state is GoalState.ABORTED and "refused the robot's position move" in last.reason, last
