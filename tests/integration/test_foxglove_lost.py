"""Lost robots seen fast (#29 item 4): the fleet view marks a robot lost when its gateway's host drops off, and back after.

Against real processes: two simulated robots, each with a gateway of its
own, and the fleet view. Freezing r2's gateway (SIGSTOP: its host is cut
off; its Zenoh link and liveliness token stay until a lease would end, only
its health stops) marks r2 lost on ``/fleet/summary`` and ``/fleet/log``
while r1 stays up; thawing it brings r2 back, with no restart. Killing it
(its token goes) marks it lost again. The 2.5 s rule itself is tested on a
fake clock in ``test_foxglove_fleet.py``; here the figures are printed.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path
from typing import Any

import pytest
from helpers import Child, free_port, zenoh_listen_args
from unit.foxglove.test_fleet import FleetClient

from blackmetal.runtime.fleet import load_fleet


def _summary(client: FleetClient) -> dict[str, Any] | None:
    return json.loads(client.messages[1][-1]) if client.messages[1] else None


def _rows(client: FleetClient) -> dict[str, str]:
    summary = _summary(client)
    return {row["id"]: row["link"] for row in summary["robots"]} if summary else {}


@pytest.mark.integration
def test_a_robot_whose_gateway_stops_is_lost_within_seconds_and_back_with_no_restart(children: list[Child], tmp_path: Path) -> None:
    port = free_port()
    fleet = tmp_path / "fleet.toml"
    sim = Child(["-m", "blackmetal", "sim", "--robots", "2", "--write-fleet", str(fleet), *zenoh_listen_args(port)])
    children.append(sim)
    sim.ready()
    zargs = ["-e", f"tcp/127.0.0.1:{port}", "--no-multicast-scouting"]
    gateways = {}
    for robot in load_fleet(fleet):
        gateways[robot.id] = Child(
            [
                "-m",
                "blackmetal.gateway",
                "--control-port",
                str(robot.control_port),
                "--log-port",
                str(robot.log_port),
                "--prefix",
                robot.prefix,
                *zargs,
            ]
        )
        children.append(gateways[robot.id])
    for gateway in gateways.values():
        gateway.ready()
    view = Child(["-m", "blackmetal", "foxglove", "--fleet", str(fleet), "--port", "0", *zargs])
    children.append(view)
    client = FleetClient(view.ready()["url"])
    frozen = gateways["r2"].proc.pid
    try:
        client.wait(lambda: {"/fleet/summary", "/fleet/log"} <= set(client.channels()), "the fleet's channels")
        client.subscribe(1, "/fleet/summary")
        client.subscribe(2, "/fleet/log")
        client.wait(lambda: (s := _summary(client)) and s["robots_up"] == 2, "both robots up")

        os.kill(frozen, signal.SIGSTOP)  # r2's host drops off: no health, the token lingers
        cut = time.monotonic()
        client.wait(lambda: _rows(client).get("r2", "").startswith("lost"), "r2 lost")
        lost_after = time.monotonic() - cut
        assert _rows(client)["r1"] == "connected/connected", "r1 is not touched"
        assert "no health for 2.5 s" in _rows(client)["r2"] and _summary(client)["lost"] == ["r2"]  # type: ignore[index]
        client.wait(lambda: any(b"r2 lost" in m for m in client.messages[2]), "the fleet's log: r2 lost")

        os.kill(frozen, signal.SIGCONT)
        healed = time.monotonic()
        client.wait(lambda: _rows(client).get("r2") == "connected/connected", "r2 back")
        back_after = time.monotonic() - healed
        client.wait(lambda: any(b"r2 back" in m for m in client.messages[2]), "the fleet's log: r2 back")
        print(f"\nr2 marked lost {lost_after:.2f} s after its gateway froze, back {back_after:.2f} s after it thawed")

        gateways["r2"].proc.kill()  # its token goes
        client.wait(lambda: "liveliness token gone" in _rows(client).get("r2", ""), "r2 lost by its token")
        assert _rows(client)["r1"] == "connected/connected"
    finally:
        if gateways["r2"].proc.poll() is None:
            os.kill(frozen, signal.SIGCONT)
        client.close()
    assert view.stop() == 0
