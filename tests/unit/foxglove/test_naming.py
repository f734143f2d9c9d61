"""The view's names: one robot's bare, a fleet's robot's under its id; the words of the protocol (pure)."""

from __future__ import annotations

from blackmetal.foxglove import naming

IDS = ("r1", "r2", "r3")


def test_a_fleets_robot_is_named_under_its_id_and_one_robots_view_as_before() -> None:
    assert (
        naming.robot_namespace("r3") == "/r3"
        and naming.robot_frame("r3", "odom") == "r3/odom"
        and naming.robot_frame("r3", "base_link") == "r3/base_link"
    )
    assert (
        naming.control_topic("/r3", naming.Control.CMD_VEL) == "/r3/cmd_vel" and naming.control_topic("", naming.Control.ESTOP) == "/estop"
    )
    assert (
        naming.service_name("/r3", naming.Service.SET_ESTOP) == "/r3/set_estop"
        and naming.service_name("", naming.Service.RESET_ODOMETRY) == "reset_odometry"
    )
    assert naming.robot_of("/r3/cmd_vel", IDS) == "r3" and naming.robot_of("/r1/set_estop", IDS) == "r1"
    for name in ("/r4/cmd_vel", "/r3", "/r3/", "r3/cmd_vel", "/cmd_vel", "set_estop", "//r3/cmd_vel"):
        assert naming.robot_of(name, IDS) is None, name


def test_what_clients_may_publish_and_call_is_said_from_one_table() -> None:
    assert naming.takes() == naming.takes("") == "/cmd_vel (geometry_msgs/msg/Twist) and /estop (std_msgs/msg/Bool), JSON-encoded"
    assert naming.takes("/r2").startswith("/r2/cmd_vel (geometry_msgs/msg/Twist) and /r2/estop")
    assert all(naming.CONTROL_SCHEMAS[c][0].count("/msg/") == 1 for c in naming.Control), "the ROS 2 spelling first"
    for service, spec in naming.SERVICE_SPECS.items():
        assert spec.request["title"] == f"{spec.type}_Request" and spec.response["title"] == f"{spec.type}_Response", service
        assert spec.response["properties"]["success"] == {"type": "boolean"}
    assert naming.SERVICE_SPECS[naming.Service.SET_ESTOP].request["required"] == ["data"]


def test_the_3d_panels_topics_and_what_they_carry() -> None:
    assert naming.nav_topic("/r2", naming.NavTopic.GOAL_POSE) == "/r2/goal_pose"
    assert {t.value for t in naming.NavTopic} == {"/goal_pose", "/move_base_simple/goal", "/initialpose", "/clicked_point"}
    assert all(naming.NAV_SCHEMAS[t][0].count("/msg/") == 1 and naming.NAV_SCHEMAS[t][1].count("/") == 1 for t in naming.NavTopic)
    said = naming.nav_takes("/r2")
    assert "/r2/goal_pose and /r2/move_base_simple/goal" in said and "nav/goal" in said and "/r2/initialpose" in said
