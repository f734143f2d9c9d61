"""``blackmetal nav``: its options, its start (ready line, alive/nav, the queryables), one navigation per prefix, and
its stop; the core is the brief's interface, stood in for by a fake (the real one is the core helper's)."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest
import zenoh
from helpers import client_config, free_port

from blackmetal.nav import main
from blackmetal.nav.settings import NavSettings
from blackmetal.runtime.zenoh_setup import ZenohSettings
from blackmetal.schemas import ConfigError, MapPose, decode

from .fake_core import FakeNavCore


def test_the_options_are_the_settings_and_the_fleet() -> None:
    args = main.build_parser().parse_args(["--map-pose=1,-2,0.5", "--max-speed", "0.2", "--fleet", "robots.toml"])
    assert (args.map_pose, args.max_speed, args.fleet) == (["1", "-2", "0.5"], 0.2, "robots.toml")
    assert main.COMMAND.name == "nav" and main.COMMAND.settings is NavSettings and main.COMMAND.fleet is not None


def test_a_fleet_refuses_the_settings_of_one_robot(capsys: pytest.CaptureFixture[str]) -> None:
    assert main.main(["--fleet", "robots.toml", "--map-pose", "1,2,0"]) == 2
    assert "--map-pose is for one robot and cannot be used with --fleet" in capsys.readouterr().err


async def client_of(port: int) -> zenoh.Session:
    """A client of the service's listener, once it listens."""
    for _ in range(100):
        try:
            return await asyncio.to_thread(zenoh.open, client_config(port))
        except zenoh.ZError:
            await asyncio.sleep(0.05)
    raise AssertionError(f"nothing listens on port {port}")


def test_it_serves_on_its_prefix_and_refuses_a_second_navigation_there(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(main, "NavCore", FakeNavCore)
    port = free_port()
    listen = ZenohSettings(listen=[f"tcp/127.0.0.1:{port}"])
    settings = NavSettings(map_pose=[1.0, 2.0, 0.5], map="floor2", zenoh=listen)

    async def scenario() -> None:
        stop = asyncio.Event()
        serving = asyncio.ensure_future(main.serve(settings, stop))
        with await client_of(port) as client:

            def alive() -> list[str]:
                return [str(r.ok.key_expr) for r in client.liveliness().get("robot/alive/*", timeout=2) if r.ok is not None]

            for _ in range(200):
                if "robot/alive/nav" in await asyncio.to_thread(alive):
                    break
                await asyncio.sleep(0.02)
            else:
                raise AssertionError("no robot/alive/nav")
            replies = await asyncio.to_thread(lambda: [r.ok for r in client.get("robot/nav/map_pose", timeout=5) if r.ok])
            placed = decode(MapPose, replies[0].payload.to_bytes())
            assert (placed.x, placed.y, placed.yaw, placed.map, placed.by) == (1.0, 2.0, 0.5, "floor2", "settings")
            second = NavSettings(zenoh=ZenohSettings(connect=[f"tcp/127.0.0.1:{port}"]))
            with pytest.raises(ConfigError, match=r"another navigation service is already alive on prefix 'robot' \(robot/alive/nav\)"):
                await asyncio.wait_for(main.serve(second, asyncio.Event()), 10)
            stop.set()
            await asyncio.wait_for(serving, 5)
            assert "robot/alive/nav" not in await asyncio.to_thread(alive)

    asyncio.run(scenario())
    out = capsys.readouterr().out
    assert "blackmetal nav ready: goals on robot/nav/goal -> robot/cmd_vel/nav; odom at (1, 2, 0.5 rad) on map 'floor2'" in out


def test_run_stops_on_a_signal_and_says_nothing_more(monkeypatch: pytest.MonkeyPatch) -> None:
    """The command runs the service through the runtime's entry: a settings mistake is exit 2, before any Zenoh."""
    seen: dict[str, Any] = {}

    def fake_run_service(name: str, load: Any, serve: Any) -> int:
        seen.update(name=name, settings=load())
        return 0

    monkeypatch.setattr("blackmetal.runtime.entry.run_service", fake_run_service)
    assert main.main(["--prefix", "fleet/a", "--geofence=-1,-1,1,1"]) == 0
    assert seen["name"] == "nav" and seen["settings"].prefix == "fleet/a" and seen["settings"].fence() == (-1.0, -1.0, 1.0, 1.0)
