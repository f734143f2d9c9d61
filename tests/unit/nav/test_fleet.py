"""``blackmetal nav --fleet``: each robot's settings from its [robot.nav] table, its poses from a ring the loop drains,
and a bug in one robot's navigation restarts that robot alone. The core is the brief's interface (a fake here)."""

from __future__ import annotations

import asyncio
import json
import math
from typing import Any

import pytest
import zenoh
from helpers import client_config, free_port

from blackmetal.nav import fleet
from blackmetal.nav.settings import NavSettings
from blackmetal.runtime.burst import PutBurst
from blackmetal.runtime.fleet import FleetRobot, parse_fleet
from blackmetal.runtime.service import Member
from blackmetal.runtime.zenoh_setup import ZenohSettings

from .fake_core import FakeNavCore


def robots() -> list[FleetRobot]:
    return parse_fleet(
        {
            "robot": [
                {"id": "r1", "control_port": 1, "log_port": 2, "nav": {"map_pose": [5, 0, math.pi / 2], "geofence": [0, 0, 10, 10]}},
                {"id": "r2", "control_port": 3, "log_port": 4},
            ]
        }
    )


def test_each_robot_has_its_prefix_and_its_own_place_on_the_map() -> None:
    first, second = fleet.fleet_settings(NavSettings(max_speed=0.2), robots())
    assert (first.prefix, first.map_pose, first.fence(), first.max_speed) == (
        "fleet/r1",
        [5.0, 0.0, math.pi / 2],
        (0.0, 0.0, 10.0, 10.0),
        0.2,
    )
    assert (second.prefix, second.map_pose, second.fence(), second.max_speed) == ("fleet/r2", [0.0, 0.0, 0.0], None, 0.2)


def test_a_member_is_built_supervised_and_follows_its_poses_from_a_move(session: zenoh.Session, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(fleet, "NavCore", FakeNavCore)
    robot = robots()[0]

    async def scenario() -> None:
        member = Member(fleet.ROLE, robot, fleet.fleet_settings(NavSettings(), [robot])[0], session, PutBurst()).start()
        core = member.host.core
        assert member.host.supervised and core.geofence == (0.0, 0.0, 10.0, 10.0) and core.map_pose().yaw == math.pi / 2
        session.put("fleet/r1/pose", b'{"k":0}')
        await asyncio.sleep(0.05)
        member.drain()
        assert core.named("pose") == []  # idle: its poses are not followed
        await asyncio.to_thread(lambda: list(session.get("fleet/r1/nav/move", payload=b"{}", timeout=5)))
        for k in range(1, 4):
            session.put("fleet/r1/pose", b'{"k":%d}' % k)
        await asyncio.sleep(0.05)
        member.drain()
        assert [call[1] for call in core.named("pose")] == [b'{"k":3}']  # a move: followed, the newest taken
        member.close()

    asyncio.run(scenario())


def test_the_fleet_serves_every_robot_and_a_bug_restarts_one_robot_alone(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(fleet, "NavCore", FakeNavCore)
    port = free_port()
    base = NavSettings(zenoh=ZenohSettings(listen=[f"tcp/127.0.0.1:{port}"]))

    async def scenario() -> None:
        stop = asyncio.Event()
        serving = asyncio.ensure_future(fleet.serve(base, robots(), stop))
        client = None
        for _ in range(100):
            try:
                client = await asyncio.to_thread(zenoh.open, client_config(port))
                break
            except zenoh.ZError:
                await asyncio.sleep(0.05)
        assert client is not None
        with client:
            errors: list[dict[str, Any]] = []
            client.declare_subscriber("fleet/r1/errors", lambda s: errors.append(json.loads(s.payload.to_bytes())))

            def alive() -> set[str]:
                return {str(r.ok.key_expr) for r in client.liveliness().get("fleet/*/alive/nav", timeout=2) if r.ok is not None}

            async def until(condition: Any, what: str) -> Any:
                for _ in range(300):
                    if value := await asyncio.to_thread(condition):
                        return value
                    await asyncio.sleep(0.02)
                raise AssertionError(f"timed out waiting for {what}")

            await until(lambda: alive() == {"fleet/r1/alive/nav", "fleet/r2/alive/nav"}, "both robots' navigation")
            await asyncio.to_thread(lambda: list(client.get("fleet/r1/nav/goal", payload=b"bug", timeout=2)))  # r1's handling fails
            await until(lambda: errors, "r1's failure on its errors key")
            assert errors[0]["source"] == "nav" and errors[0]["key"] == "fleet/r1/errors"
            assert "navigation of robot 1 (id 'r1') failed" in errors[0]["reason"] and "starting again from zero" in errors[0]["reason"]
            answer = await until(lambda: [r.ok for r in client.get("fleet/r2/nav/goal", payload=b"{}", timeout=2) if r.ok], "r2's answer")
            assert json.loads(answer[0].payload.to_bytes())["accepted"]  # r2 went on
            await until(lambda: [r.ok for r in client.get("fleet/r1/nav/goal", payload=b"{}", timeout=2) if r.ok], "r1 again")
            stop.set()
            await asyncio.wait_for(serving, 10)

    asyncio.run(scenario())
    assert "blackmetal nav ready: a fleet of 2 robots, goals on fleet/r1/nav/goal" in capsys.readouterr().out
