"""teleop: keys to commands with an injected clock, and the status line."""

from __future__ import annotations

from blackmetal.schemas import GatewayHealth, LinkHealth, make_pose
from blackmetal.tools.teleop import Teleop, _status, parse_keys


def test_teleop_keys_to_commands() -> None:
    assert parse_keys(b"w\x1b[Aa \x1b[Dq\x03") == ["w", "up", "a", "space", "left", "q", "quit"]
    t = Teleop(speed=0.2, turn_rate=0.8, hold=0.5, rate=10.0)
    ((kind, twist),) = t.on_key("up", 0.0)
    assert kind == "cmd_vel" and twist.linear.x == 0.2  # type: ignore[attr-defined]
    assert t.on_key("up", 0.03) == []  # key repeat faster than 10 Hz: no extra message
    assert t.tick(0.05) == [] and len(t.tick(0.11)) == 1  # 10 Hz while held
    ((kind, stop),) = t.tick(0.7)  # released: one zero command
    assert stop.linear.x == 0.0 and t.tick(0.8) == []  # type: ignore[attr-defined]
    msgs = t.on_key("e", 1.0)
    assert msgs[0][0] == "estop" and msgs[0][1].engaged is True  # type: ignore[attr-defined]
    ((kind, release),) = t.on_key("e", 1.1)  # e again releases, on the release key
    assert kind == "estop_release" and release.engaged is False  # type: ignore[attr-defined]


def test_the_status_line_says_who_drives_and_the_estop() -> None:
    teleop = Teleop(speed=0.2, turn_rate=0.8)
    teleop.on_key("w", 0.0)
    link = LinkHealth(state="connected")
    health = GatewayHealth(stamp=0.0, control=link, log=link, estop=True, active_source="teleop")
    line = _status(teleop, make_pose(0.0, 1.0, -2.0, 0.0), health)
    assert line.startswith("cmd v=+0.20 w=+0.00 (max 0.20 m/s) | pose x=+1.000 y=-2.000 yaw=  +0.0°")
    assert line.endswith("link connected | driving: teleop | E-STOP ENGAGED: commands refused, e releases")
    assert _status(Teleop(), None, None) == "cmd v=+0.00 w=+0.00 (max 0.20 m/s)"
