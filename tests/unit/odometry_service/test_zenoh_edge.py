"""The odometry's Zenoh edge: impulses in, poses out, queries and resets answered, hostile input reported."""

from __future__ import annotations

import asyncio
import json

import pytest
import zenoh
from helpers import Child, client_config, free_port, wait_for, zenoh_listen_args

from blackmetal.odometry_service.core import OdometryCore
from blackmetal.odometry_service.host import OdometryHost
from blackmetal.odometry_service.params import OdometryParams
from blackmetal.odometry_service.zenoh_edge import OdometryZenoh
from blackmetal.schemas import Keys, Pose, WheelImpulses, decode, encode


def test_impulses_become_poses_and_the_queryables_answer(session: zenoh.Session) -> None:
    keys = Keys("edge/odo")
    poses: list[Pose] = []
    subscriber = session.declare_subscriber(keys.pose, lambda s: poses.append(decode(Pose, s.payload.to_bytes())))

    async def scenario() -> None:
        edge = OdometryZenoh(session, keys)
        host = OdometryHost(OdometryCore(OdometryParams(), keys, edge.publish))
        edge.attach(host, asyncio.get_running_loop())
        try:
            for seq in range(1, 4):
                sample = WheelImpulses(seq=seq, stamp=1.0 + 0.02 * seq, left=100, right=-100, mono=0.02 * seq, source="gw")
                session.put(keys.impulses, encode(sample))
            for _ in range(500):
                if len(poses) == 3:
                    break
                await asyncio.sleep(0.01)
            latest = await asyncio.to_thread(lambda: [r.ok for r in session.get(keys.pose, timeout=5) if r.ok])
            assert decode(Pose, latest[0].payload.to_bytes()).x == poses[-1].x > 0.0
            bad = await asyncio.to_thread(lambda: list(session.get(keys.odometry_reset, payload=b"[", timeout=5)))
            assert bad[0].err is not None and b"invalid PoseReset" in bad[0].err.payload.to_bytes()
            assert edge.drain() == 0  # no ring: impulses came through their callback
        finally:
            edge.close()

    try:
        asyncio.run(scenario())
    finally:
        subscriber.undeclare()
    assert len(poses) == 3


@pytest.mark.integration
def test_hostile_impulses_and_resets_on_zenoh(children: list[Child]) -> None:
    zport = free_port()
    odometry = Child(["-m", "blackmetal.odometry_service", *zenoh_listen_args(zport)])
    children.append(odometry)
    odometry.ready()
    with zenoh.open(client_config(zport)) as session:
        errors: list[dict[str, object]] = []
        session.declare_subscriber("robot/errors", lambda s: errors.append(json.loads(s.payload.to_bytes())))
        wait_for(lambda: [r for r in session.get("robot/pose", timeout=5) if r.ok is not None], what="the pose queryable")
        block = zenoh.CongestionControl.BLOCK
        for payload in (b"\x00garbage", b'{"seq":1,"stamp":Infinity,"left":0,"right":0}', b"A" * (1 << 20)):
            session.put("robot/wheels/impulses", payload, congestion_control=block)
        wait_for(lambda: len(errors) >= 3, what="three error reports")
        assert {e["key"] for e in errors} == {"robot/wheels/impulses"}
        replies = list(session.get("robot/odometry/reset", payload=b'{"x":"no"}', timeout=5))
        assert replies and replies[0].err is not None and b"invalid PoseReset" in replies[0].err.payload.to_bytes()
        replies = list(session.get("robot/odometry/reset", payload=b'{"x":1.0,"yaw":0.5}', timeout=5))
        pose = decode(Pose, replies[0].ok.payload.to_bytes())
        assert (pose.x, pose.yaw) == (1.0, 0.5)
        assert odometry.proc.poll() is None
