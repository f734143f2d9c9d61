"""The simulator's ground truth costs nothing while nobody subscribes to it (a fleet of 100 spent a third of the
simulator on it), and is published as before once someone does."""

from __future__ import annotations

import time

import zenoh
from helpers import wait_for

from blackmetal.schemas import Keys, Pose, decode
from blackmetal.sim.physics import SimRobot
from blackmetal.sim.zenoh_edge import SimZenoh


class CountingRobot(SimRobot):
    """A simulated robot that counts the true poses asked of it (what publishing the truth encodes)."""

    poses = 0

    def pose(self, stamp: float) -> Pose:
        self.poses += 1
        return super().pose(stamp)


def test_the_truth_is_published_only_while_someone_subscribes(session: zenoh.Session) -> None:
    robot = CountingRobot(now=time.monotonic())
    edge = SimZenoh(session, Keys("robot"), robot, time.monotonic)
    try:
        assert not edge.watched
        for _ in range(5):
            edge.tick()
        assert robot.poses == 0  # nobody watches: nothing built, nothing put

        got: list[Pose] = []
        subscriber = session.declare_subscriber("robot/sim/truth", lambda s: got.append(decode(Pose, s.payload.to_bytes())))
        wait_for(lambda: edge.watched, what="the matching status to say someone subscribes")
        wait_for(lambda: edge.tick() or got, what="a true pose")
        assert robot.poses >= 1

        subscriber.undeclare()
        wait_for(lambda: not edge.watched, what="the matching status to say nobody subscribes")
        before = robot.poses
        for _ in range(5):
            edge.tick()
        assert robot.poses == before
    finally:
        edge.close()


def test_the_truth_is_still_answered_to_a_get_while_nobody_subscribes(session: zenoh.Session) -> None:
    import asyncio

    robot = SimRobot(now=time.monotonic())
    edge = SimZenoh(session, Keys("robot"), robot, time.monotonic)
    loop = asyncio.new_event_loop()
    try:
        edge.attach(loop)
        replies = session.get("robot/sim/truth", timeout=5.0)
        # the queryable's answer goes through the loop's intake: run the loop until the reply is there
        pose = None
        deadline = time.monotonic() + 10.0
        while pose is None and time.monotonic() < deadline:
            loop.run_until_complete(asyncio.sleep(0.02))
            reply = replies.try_recv()
            if reply is not None and reply.ok is not None:
                pose = decode(Pose, reply.ok.payload.to_bytes())
        assert pose is not None and edge.watched is False
    finally:
        edge.close()
        loop.close()
