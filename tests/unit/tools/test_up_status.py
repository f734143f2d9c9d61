"""up's status lines, from fed health reports alone (no processes), and the drive help it prints."""

from __future__ import annotations

import time

from blackmetal.runtime.fleet import numbered_fleet
from blackmetal.schemas import GatewayHealth, Keys, LinkHealth
from blackmetal.tools.up.status import FleetStatus, drive_help, fleet_drive_help, goto_help


class NoSession:
    """Stands in for a Zenoh session where a status line is rendered from fed health: nothing arrives."""

    def liveliness(self) -> "NoSession":
        return self

    def declare_subscriber(self, *args: object, **kwargs: object) -> "NoSession":
        return self

    def try_recv(self) -> None:  # an empty pose ring
        return None

    def undeclare(self) -> None:
        return None


def test_the_status_says_connecting_before_a_robot_was_ever_up_and_down_after() -> None:
    """The fleet status line's words, from health reports alone (no processes)."""
    from blackmetal.schemas import GatewayHealth

    robots = numbered_fleet(2)
    status = FleetStatus(NoSession(), robots)  # type: ignore[arg-type]

    def health(state: str) -> GatewayHealth:
        return GatewayHealth(stamp=0.0, control=LinkHealth(state=state), log=LinkHealth(state=state))

    status.health["fleet/r1"] = (health("down"), time.monotonic())
    line = status.render()
    assert "connecting 2: r1, r2" in line and "link down" not in line and "no health" not in line, line
    status.health["fleet/r1"] = (health("connected"), time.monotonic())
    status.health["fleet/r2"] = (health("connected"), time.monotonic())
    assert "connecting" not in status.render()
    status.health["fleet/r2"] = (health("down"), time.monotonic())
    assert "link down 1: r2" in status.render()
    refused = LinkHealth(state="down", reason="cannot connect to 127.0.0.1:9: connection refused")
    status.health["fleet/r2"] = (GatewayHealth(stamp=0.0, control=refused, log=refused), time.monotonic())
    assert "link down 1: r2 (r2: cannot connect to 127.0.0.1:9: connection refused)" in status.render()  # why, not just down


def test_the_status_says_when_the_fleet_is_behind_its_rate() -> None:
    from blackmetal.schemas import GatewayHealth

    status = FleetStatus(NoSession(), numbered_fleet(3), poll_hz=50.0)  # type: ignore[arg-type]
    link = LinkHealth(state="connected")
    for rid, hz in (("r1", 49.0), ("r2", 48.0), ("r3", 47.0)):
        status.health[f"fleet/{rid}"] = (GatewayHealth(stamp=0.0, control=link, log=link, poll_hz=hz), time.monotonic())
    assert "BEHIND" not in status.render()
    for rid, hz in (("r1", 41.0), ("r2", 40.0), ("r3", 48.0)):
        status.health[f"fleet/{rid}"] = (GatewayHealth(stamp=0.0, control=link, log=link, poll_hz=hz), time.monotonic())
    assert "BEHIND 50 Hz: the host is short of CPU" in status.render()


def test_the_drive_help_says_how_often_to_publish() -> None:
    text = drive_help(Keys("robot"), "tcp/127.0.0.1:7447", cmd_timeout=0.5)
    assert text.startswith("Drive it from any Zenoh client (commands time out after 0.5 s: publish at 5 Hz or more):")
    assert "blackmetal teleop -e tcp/127.0.0.1:7447" in text and text.endswith("Ctrl-C stops everything.")
    assert "commands never time out: publish a zero to stop" in drive_help(Keys("robot"), "tcp/x:1", cmd_timeout=0.0)
    fleet = fleet_drive_help(numbered_fleet(3), "tcp/127.0.0.1:7447", 0.5)
    assert fleet.startswith("Drive one robot from any Zenoh client, by its prefix (fleet/r1 ... fleet/r3;")
    assert "blackmetal estop on --prefix fleet/r1 -e tcp/127.0.0.1:7447" in fleet


def test_the_goto_help_names_the_endpoint_and_a_prefix_other_than_robot() -> None:
    assert goto_help(Keys("robot"), "tcp/127.0.0.1:7447").splitlines() == [
        "Send it somewhere (the navigation service, robot/nav/goal):",
        "  blackmetal goto 0.5 0.3 90 -e tcp/127.0.0.1:7447    # x, y in metres, heading in degrees; Ctrl-C cancels",
    ]
    assert "blackmetal goto 0.5 0.3 90 -e tcp/x:1 --prefix lab/a " in goto_help(Keys("lab/a"), "tcp/x:1")
    assert "blackmetal goto 0.5 0.3 90 --prefix fleet/r1 -e tcp/127.0.0.1:7447" in fleet_drive_help(
        numbered_fleet(3), "tcp/127.0.0.1:7447", 0.5
    )
