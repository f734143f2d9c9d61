"""The gateway's health as ROS diagnostics, for Foxglove's Diagnostics panels (pure)."""

from __future__ import annotations


def test_diagnostics_show_the_gateways_health_as_ros_diagnostics() -> None:
    from blackmetal.foxglove.diagnostics import diagnostics
    from blackmetal.runtime.diagnostics import Level
    from blackmetal.schemas import GatewayHealth, LinkHealth

    health = GatewayHealth(stamp=12.5, control=LinkHealth("connected"), log=LinkHealth("down"), estop=True, active_source="foxglove")
    array = diagnostics(health, "robot")
    levels = {status["name"]: status["level"] for status in array["status"]}
    assert array["header"]["stamp"] == {"sec": 12, "nsec": 500_000_000}
    assert levels["gateway: e-stop"] == levels["gateway: log link"] == Level.ERROR
    assert levels["gateway: control link"] == Level.OK
    assert all(
        status["hardware_id"] == "robot" and all(isinstance(v["value"], str) for v in status["values"]) for status in array["status"]
    )
    assert "driven by foxglove" in {status["message"] for status in array["status"]}


def test_a_conflict_and_lost_replies_show_their_levels_and_the_schema_is_ros() -> None:
    from blackmetal.foxglove.diagnostics import DIAGNOSTICS_SCHEMA, diagnostics
    from blackmetal.runtime.diagnostics import Level
    from blackmetal.schemas import GatewayHealth, LinkHealth

    health = GatewayHealth(
        stamp=1.0, control=LinkHealth("connected"), log=LinkHealth("connected"), conflict_with="teleop", lost_replies=2, poll_hz=50.0
    )
    statuses = {status["name"]: status for status in diagnostics(health, "fleet/r1")["status"]}
    assert statuses["gateway: commands"]["level"] > Level.OK and "teleop" in statuses["gateway: commands"]["message"]
    exchange = statuses["gateway: robot exchange"]
    assert exchange["level"] > Level.OK and exchange["message"].startswith("50 Hz polls")
    assert {"key": "lost_replies", "value": "2"} in exchange["values"]
    assert statuses["gateway: e-stop"]["level"] == Level.OK
    assert DIAGNOSTICS_SCHEMA["title"] == "diagnostic_msgs/msg/DiagnosticArray"
