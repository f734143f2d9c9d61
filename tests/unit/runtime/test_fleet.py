"""The fleet file: one sentence naming the robot for every mistake; each service takes its own part."""

from __future__ import annotations

import tomllib

import pytest

from blackmetal.gateway.settings import GatewaySettings
from blackmetal.odometry_service.settings import OdometrySettings
from blackmetal.runtime.fleet import load_fleet, numbered_fleet, parse_fleet, write_fleet
from blackmetal.schemas import ConfigError

GOOD = """
[[robot]]
id = "r1"
host = "127.0.0.1"
control_port = 6651
log_port = 6641
impulses_left = 1015.0
[robot.gateway]
poll_hz = 40
[robot.odometry]
max_gap = 0.4

[[robot]]
id = "r2"
control_port = 6652
log_port = 6642
prefix = "lab/east/r2"
"""


def test_a_fleet_file_gives_each_service_its_part() -> None:
    r1, r2 = parse_fleet(tomllib.loads(GOOD))
    assert (r1.prefix, r2.prefix, r2.host) == ("fleet/r1", "lab/east/r2", "127.0.0.1")
    gw = r1.settings("gateway", GatewaySettings(), {"robot": r1.host, "control_port": r1.control_port, "prefix": r1.prefix})
    assert (gw.poll_hz, gw.impulses_left, gw.control_port, gw.prefix) == (40.0, 1015.0, 6651, "fleet/r1")
    odo = r1.settings("odometry", OdometrySettings(), {"prefix": r1.prefix})
    assert (odo.max_gap, odo.impulses_left, odo.prefix) == (0.4, 1015.0, "fleet/r1")
    assert r2.settings("gateway", GatewaySettings()).poll_hz == 50.0  # the defaults where the file is silent


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            '[[robot]]\nid="a"\ncontrol_port=1\nlog_port=2\n[[robot]]\nid="a"\ncontrol_port=3\nlog_port=4\n',
            "robot 2 (id 'a'): id 'a' is already used by robot 1",
        ),
        (
            '[[robot]]\nid="a"\ncontrol_port=1\nlog_port=2\n[[robot]]\nid="b"\ncontrol_port=3\nlog_port=2\n',
            "robot 2 (id 'b'): port 127.0.0.1:2 is already used by robot 1",
        ),
        (
            '[[robot]]\nid="a"\ncontrol_port=1\nlog_port=2\nprefix="x/y"\n[[robot]]\nid="b"\ncontrol_port=3\nlog_port=4\nprefix="x/y"\n',
            "robot 2 (id 'b'): prefix 'x/y' is already",
        ),
        ('[[robot]]\nid="a"\ncontrol_port=1\nlog_port=2\npoll_hz=5\n', "robot 1 (id 'a'): unknown key 'poll_hz'"),
        ('[[robot]]\nid="a"\ncontrol_port="665"\nlog_port=2\n', "robot 1 (id 'a'): control_port must be an integer"),
        ("[[robot]]\ncontrol_port=1\nlog_port=2\n", "robot 1: id is missing"),
        ('[[robot]]\nid="a/b"\ncontrol_port=1\nlog_port=2\n', "one key chunk"),
        ('[[robot]]\nid="a\\u0000b"\ncontrol_port=1\nlog_port=2\n', "robot 1: id 'a.*b' must be 1 to 64 letters"),
        ('[[robot]]\nid="r\\u202e1"\ncontrol_port=1\nlog_port=2\n', "must be 1 to 64 letters, digits"),
        ('[[robot]]\nid="' + "x" * 100_000 + '"\ncontrol_port=1\nlog_port=2\n', "robot 1: id of 100000 characters must be 1 to 64"),
        ('[[robot]]\nid="a"\ncontrol_port=1\nlog_port=2\nprefix="fleet/../x"\n', "must not have a '.' or '..' part"),
        ('[[robot]]\nid="a"\ncontrol_port=1\nlog_port=2\nprefix="fleet/a b"\n', "without spaces or control characters"),
        ('max_robots = 0\n[[robot]]\nid="a"\ncontrol_port=1\nlog_port=2\n', "max_robots must be an integer from 1 to 10000"),
        (
            "".join(f'[[robot]]\nid="r{k}"\ncontrol_port={2 * k + 10}\nlog_port={2 * k + 11}\n' for k in range(251)),
            "251 robots, more than the 250",
        ),
        ('[[robot]]\nid="a"\ncontrol_port=1\nlog_port=2\nwheel_separation="wide"\n', "wheel_separation must be a positive number"),
        ("[robots]\n", "unknown top-level key 'robots'"),
        ("", "no [[robot]] tables"),
    ],
)
def test_mistakes_name_the_entry(text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        parse_fleet(tomllib.loads(text))


def test_a_service_table_is_checked_by_its_service() -> None:
    (robot,) = parse_fleet(tomllib.loads('[[robot]]\nid="a"\ncontrol_port=1\nlog_port=2\n[robot.gateway]\npoll_hz="fast"\n'))
    with pytest.raises(ConfigError, match=r"robot 1 \(id 'a'\): \[robot.gateway\]: poll_hz must be a number, got 'fast' \(text\)"):
        robot.settings("gateway", GatewaySettings())
    (robot,) = parse_fleet(tomllib.loads('[[robot]]\nid="a"\ncontrol_port=1\nlog_port=2\n[robot.gateway]\npolhz=5\n'))
    with pytest.raises(ConfigError, match="unknown gateway setting 'polhz'"):
        robot.settings("gateway", GatewaySettings())
    (robot,) = parse_fleet(tomllib.loads('[[robot]]\nid="a"\ncontrol_port=1\nlog_port=2\n[robot.gateway]\npoll_hz=5000\n'))
    with pytest.raises(ConfigError, match="robot 1 \\(id 'a'\\): poll_hz 5000"):
        robot.settings("gateway", GatewaySettings())


def test_numbered_fleets_round_trip_through_a_file(tmp_path) -> None:  # type: ignore[no-untyped-def]
    robots = numbered_fleet(3, first_port=7000)
    assert [(r.id, r.prefix, r.control_port, r.log_port) for r in robots][-1] == ("r3", "fleet/r3", 7004, 7005)
    path = tmp_path / "fleet.toml"
    path.write_text(write_fleet(robots))
    assert load_fleet(path) == robots
    with pytest.raises(ConfigError, match="cannot read fleet file"):
        load_fleet(tmp_path / "missing.toml")


def test_times_beyond_the_robots_bounds_are_refused_naming_the_robot() -> None:
    from blackmetal.gateway.settings import GatewaySettings

    robots = parse_fleet(tomllib.loads('[[robot]]\nid="a"\ncontrol_port=1\nlog_port=2\n[robot.gateway]\ncmd_timeout=1e9\n'))
    with pytest.raises(ConfigError, match=r"robot 1 \(id 'a'\): cmd_timeout 1e\+09 s is beyond 60 s"):
        robots[0].settings("gateway", GatewaySettings())


def test_a_generated_fleet_beyond_the_cap_says_it_was_meant() -> None:
    from blackmetal.runtime.fleet import numbered_fleet, write_fleet

    robots = parse_fleet(tomllib.loads(write_fleet(numbered_fleet(300, first_port=20000))))
    assert len(robots) == 300 and robots[-1].id == "r300"
