"""``blackmetal ros2 --fleet FILE``: one ROS node per robot, one process, the test playing rmw_zenoh's side.

Three simulated robots behind one gateway and one odometry process, and one
adapter process for all: each robot's node lives in the namespace of its id
(``/r2/odom``, frames ``r2/odom`` -> ``r2/base_footprint`` as diff_drive_controller
prefixes them, transforms on the absolute ``/tf``), a CDR Twist on
``/r3/cmd_vel`` moves r3 alone, a bad payload on ``/r1/cmd_vel`` is reported
on ``fleet/r1/errors`` and the others go on. The formats are read as in
``tests/unit/ros2/test_core.py`` and ``tests/unit/ros2/test_services.py`` (independent CDR
readers, tokens split as rmw_zenoh splits them, a service client doing what
rmw_zenoh's does). Options for one robot's node end in one sentence.
"""

from __future__ import annotations

import asyncio
import collections
import math
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh
from helpers import Child, client_config, free_port, wait_for

from blackmetal.ros2.core import Ros2Core
from blackmetal.ros2.fleet import fleet_settings, serve
from blackmetal.ros2.messages import RosCodec
from blackmetal.ros2.naming import PARAMETER_SERVICES, attachment, gid_of, tf_frame_prefix, topics
from blackmetal.ros2.ros_types import SET_BOOL
from blackmetal.ros2.settings import Ros2Settings
from blackmetal.runtime.fleet import parse_fleet
from blackmetal.runtime.zenoh_setup import ZenohSettings
from blackmetal.schemas import ConfigError, ErrorReport, GatewayHealth, Pose, decode, encode, make_pose
from unit.ros2.test_core import ODOM_HASH, TF_HASH, TWIST_HASH, read_odometry
from unit.ros2.test_services import DIAGNOSTICS_KEY, SET_BOOL_HASH, RmwZenohClient, read_diagnostics, set_bool_request

IDS = ("r1", "r2", "r3")
TF_KEY = f"0/tf/tf2_msgs::msg::dds_::TFMessage_/{TF_HASH}"


def odom_key(rid: str) -> str:
    return f"0/{rid}/odom/nav_msgs::msg::dds_::Odometry_/{ODOM_HASH}"


def twist_key(rid: str) -> str:
    return f"0/{rid}/cmd_vel/geometry_msgs::msg::dds_::Twist_/{TWIST_HASH}"


def _zargs(port: int) -> list[str]:
    return ["-e", f"tcp/127.0.0.1:{port}", "--no-multicast-scouting"]


# ------------------------------------------------------------------ pure: names, frames, settings
def test_frame_prefix_is_diff_drive_controllers() -> None:
    assert tf_frame_prefix("/r3") == "r3/" and tf_frame_prefix("/a/b") == "a/b/" and tf_frame_prefix("/") == ""
    tf = next(t for t in topics(True, absolute_tf=True) if t.name == "tf")
    assert tf.full_name("/r3") == "/tf"
    assert next(t for t in topics(True) if t.name == "tf").full_name("/r3") == "/r3/tf"  # one robot: as before


def test_fleet_settings_per_robot_and_their_mistakes() -> None:
    robots = parse_fleet(
        {
            "robot": [
                {"id": "r1", "control_port": 1, "log_port": 2},
                {"id": "r2", "control_port": 3, "log_port": 4, "prefix": "lab/b", "ros2": {"node_name": "base", "domain_id": 7}},
            ]
        }
    )
    one, two = fleet_settings(Ros2Settings(flavor="bridge"), robots)
    assert (one.namespace, one.prefix, one.node_name, one.flavor) == ("r1", "fleet/r1", "blackmetal", "bridge")
    assert not one.rmf and one.rmf_robot() == "r1"
    rmf = parse_fleet(
        {"robot": [{"id": "r1", "control_port": 1, "log_port": 2, "ros2": {"rmf": True, "rmf_name": "tiny1", "rmf_battery": 1.0}}]}
    )
    (free_fleets,) = fleet_settings(Ros2Settings(), rmf)
    assert free_fleets.rmf and free_fleets.rmf_robot() == "tiny1" and free_fleets.rmf_battery == 1.0
    twins = parse_fleet(
        {
            "robot": [
                {"id": "a", "control_port": 1, "log_port": 2, "prefix": "x/r1"},
                {"id": "b", "control_port": 3, "log_port": 4, "prefix": "y/r1"},
            ]
        }
    )
    with pytest.raises(ConfigError, match="robot 2 \\(id 'b'\\): free_fleet's name 'r1' is already robot 1 \\(id 'a'\\)'s"):
        fleet_settings(Ros2Settings(rmf=True), twins)
    assert (two.namespace, two.prefix, two.node_name, two.domain_id) == ("r2", "lab/b", "base", 7)

    def refused(*entries: dict[str, object]) -> str:
        with pytest.raises(ConfigError) as info:
            fleet_settings(Ros2Settings(), parse_fleet({"robot": list(entries)}))
        return str(info.value)

    assert "robot 1 (id '1a'): id '1a' is not a valid ROS namespace" in refused({"id": "1a", "control_port": 1, "log_port": 2})
    assert "prefix is not a [robot.ros2] setting" in refused({"id": "a", "control_port": 1, "log_port": 2, "ros2": {"prefix": "x"}})
    same = {"ros2": {"namespace": "x"}}
    message = refused({"id": "a", "control_port": 1, "log_port": 2, **same}, {"id": "b", "control_port": 3, "log_port": 4, **same})
    assert "robot 2 (id 'b'): node /x/blackmetal (domain 0) is already robot 1 (id 'a')'s" in message


@pytest.mark.slow
@pytest.mark.parametrize(
    ("option", "message"),
    [
        (["--namespace", "r1"], "--namespace is for one robot and cannot be used with --fleet"),
        (["--prefix", "fleet/r1"], "--prefix is for one robot and cannot be used with --fleet"),
        (["--node-name", "base"], "--node-name is for one robot and cannot be used with --fleet"),
    ],
)
def test_single_robot_options_with_fleet_end_in_one_sentence(tmp_path: Path, option: list[str], message: str) -> None:
    path = tmp_path / "fleet.toml"
    path.write_text('[[robot]]\nid = "r1"\ncontrol_port = 1\nlog_port = 2\n')
    command = [sys.executable, "-m", "blackmetal", "ros2", "--fleet", str(path), *option]
    result = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and result.stderr.count("\n") == 1 and message in result.stderr, result.stderr


# ------------------------------------------------------------------ on Zenoh: three robots, one adapter process
def _truths(session: zenoh.Session) -> dict[str, Pose]:
    found: dict[str, Pose] = {}
    for reply in session.get("fleet/*/sim/truth", timeout=5):
        if reply.ok is not None:
            found[str(reply.ok.key_expr).split("/")[1]] = decode(Pose, reply.ok.payload.to_bytes())
    assert set(found) == set(IDS), found
    return found


def _estop(session: zenoh.Session, rid: str) -> bool:
    replies = [r for r in session.get(f"fleet/{rid}/gateway/health", timeout=5) if r.ok is not None]
    assert replies, f"no health from {rid}"
    return decode(GatewayHealth, replies[0].ok.payload.to_bytes()).estop


@pytest.mark.integration
def test_a_fleet_of_three_ros_nodes_in_one_process(children: list[Child], tmp_path: Path) -> None:
    codec = RosCodec()
    port = free_port()
    router = Child(["-m", "blackmetal", "router", "-l", f"tcp/127.0.0.1:{port}", "--no-multicast-scouting"])
    children.append(router)
    router.ready()
    fleet = tmp_path / "fleet.toml"
    sim = Child(["-m", "blackmetal", "sim", "--robots", str(len(IDS)), "--write-fleet", str(fleet), *_zargs(port)])
    children.append(sim)
    sim.ready()
    gateway = Child(["-m", "blackmetal.gateway", "--fleet", str(fleet), "--poll-hz", "50", *_zargs(port)])
    odometry = Child(["-m", "blackmetal.odometry_service", "--fleet", str(fleet), *_zargs(port)])
    ros2 = Child(["-m", "blackmetal", "ros2", "--fleet", str(fleet), "--rmf", *_zargs(port)])
    children += [gateway, odometry, ros2]
    gateway.ready()
    odometry.ready()
    nodes = ros2.ready()["nodes"]
    assert {rid: nodes[rid]["node"] for rid in IDS} == {rid: f"/{rid}/blackmetal" for rid in IDS}
    assert nodes["r2"]["keys"]["odom"] == odom_key("r2") and nodes["r3"]["keys"]["cmd_vel"] == twist_key("r3")
    assert nodes["r2"]["keys"]["tf"] == TF_KEY and nodes["r2"]["services"]["set_estop"].startswith("0/r2/set_estop/")
    assert (
        nodes["r2"]["rmf"]["rmf/tf"] == "r2/tf"
        and nodes["r3"]["rmf"]["rmf/navigate_to_pose/_action/send_goal"] == "r3/navigate_to_pose/_action/send_goal"
    )

    with zenoh.open(client_config(port)) as session:
        odoms: list[bytes] = []
        transforms: dict[str, tuple[str, str]] = {}
        statuses: set[str] = set()
        errors: dict[str, list[ErrorReport]] = collections.defaultdict(list)
        poses: collections.Counter[str] = collections.Counter()
        session.declare_subscriber(odom_key("r2"), lambda s: odoms.append(s.payload.to_bytes()))

        def on_tf(sample: zenoh.Sample) -> None:
            for t in codec.decode(sample.payload.to_bytes(), "tf2_msgs/msg/TFMessage").transforms:
                transforms[t.child_frame_id] = (t.header.frame_id, t.child_frame_id)

        session.declare_subscriber(TF_KEY, on_tf)
        rmf_tf: dict[str, list[tuple[str, str]]] = {}
        session.declare_subscriber(  # free_fleet's <robot>/tf: the robot's own frames, not prefixed (free_fleet prefixes them)
            "*/tf",
            lambda s: rmf_tf.__setitem__(
                str(s.key_expr).split("/")[0],
                [(t.header.frame_id, t.child_frame_id) for t in codec.decode(s.payload.to_bytes(), "tf2_msgs/msg/TFMessage").transforms],
            ),
        )
        session.declare_subscriber(DIAGNOSTICS_KEY, lambda s: statuses.update(read_diagnostics(s.payload.to_bytes())))
        session.declare_subscriber(
            "fleet/*/errors", lambda s: errors[str(s.key_expr).split("/")[1]].append(decode(ErrorReport, s.payload.to_bytes()))
        )
        session.declare_subscriber("fleet/*/pose", lambda s: poses.update([str(s.key_expr).split("/")[1]]))

        # the ROS graph: one node per robot in its namespace, its topics and services under it, /tf and /diagnostics absolute
        def tokens() -> list[list[str]]:
            return [str(r.ok.key_expr).split("/") for r in session.liveliness().get("@ros2_lv/0/**", timeout=5) if r.ok is not None]

        wait_for(
            lambda: len(tokens()) == 3 * 26,
            what="3 nodes' tokens (node, 10 topics with /cmd_vel twice, 8 services, the action's 5, 2 pose topics each)",
        )
        graph = tokens()
        node_tokens = [t for t in graph if t[5] == "NN"]
        assert sorted(t[7] for t in node_tokens) == ["%r1", "%r2", "%r3"] and {t[8] for t in node_tokens} == {"blackmetal"}
        assert len({t[3] for t in node_tokens}) == 3 and len({t[4] for t in graph}) == 3 * 26  # ids unique in the session
        for rid in IDS:
            names = {t[9] for t in graph if t[7] == f"%{rid}" and t[5] != "NN"}
            assert names == {f"%{rid}%cmd_vel", f"%{rid}%estop", f"%{rid}%odom", f"%{rid}%joint_states", "%tf", "%diagnostics"} | {
                f"%{rid}%robot_description",
                "%tf_static",
                f"%{rid}%set_estop",
                f"%{rid}%reset_odometry",
                "%parameter_events",
            } | {f"%{rid}%blackmetal%{name}" for name in PARAMETER_SERVICES} | {
                f"%{rid}%navigate_to_pose%_action%{name}" for name in ("send_goal", "cancel_goal", "get_result", "feedback", "status")
            } | {f"%{rid}%goal_pose", f"%{rid}%initialpose"}, names

        # /r2/odom: its frames prefixed as diff_drive_controller does; /tf carries every robot's
        wait_for(lambda: len(odoms) >= 5, what="/r2/odom")
        odom = read_odometry(odoms[-1])
        assert (odom["frame"], odom["child"]) == ("r2/odom", "r2/base_footprint")
        wait_for(lambda: {f"{rid}/base_footprint" for rid in IDS} <= set(transforms), what="/tf from every robot")
        assert all(transforms[f"{rid}/base_footprint"] == (f"{rid}/odom", f"{rid}/base_footprint") for rid in IDS)
        wait_for(lambda: set(IDS) <= set(rmf_tf), what="free_fleet's <robot>/tf from every robot")
        assert all(rmf_tf[rid] == [("odom", "base_footprint")] for rid in IDS), rmf_tf  # no navigation service: no map yet
        wait_for(lambda: {f"{rid}/blackmetal: robot link" for rid in IDS} <= statuses, what="every node's statuses on /diagnostics")

        # a CDR Twist on /r3/cmd_vel moves r3 alone
        before = _truths(session)
        gid = gid_of("@ros2_lv/0/test/0/1/MP/%/%/teleop/%r3%cmd_vel")
        twist = codec.encode_twist(0.3, 0.0)
        for seq in range(1, 16):
            session.put(twist_key("r3"), twist, attachment=attachment(seq, time.time_ns(), gid))
            time.sleep(0.1)
        wait_for(lambda: abs(_truths(session)["r3"].v) < 1e-9, what="r3 to stop after its commands")
        after = _truths(session)
        moved = {rid: math.hypot(after[rid].x - before[rid].x, after[rid].y - before[rid].y) for rid in IDS}
        assert moved["r3"] > 0.15 and moved["r1"] == moved["r2"] == 0.0, moved

        # /r3/set_estop, called as rmw_zenoh's client calls it, engages r3's e-stop alone
        client = RmwZenohClient(session, "r3/set_estop", SET_BOOL, SET_BOOL_HASH, entity_id=1)
        success, message, _ = client.call(set_bool_request(True))
        assert success, message
        assert _estop(session, "r3") and not _estop(session, "r1") and not _estop(session, "r2")
        success, message, _ = client.call(set_bool_request(False))
        assert success and not _estop(session, "r3"), message

        # a bad payload on /r1/cmd_vel is reported on fleet/r1/errors; r2 keeps posing and publishing /r2/odom
        session.put(twist_key("r1"), twist[:30])
        wait_for(lambda: any(e.key == twist_key("r1") for e in errors["r1"]), what="the bad /r1/cmd_vel reported on fleet/r1/errors")
        assert not any(e.source == "ros2" for rid in ("r2", "r3") for e in errors[rid])
        seen_odoms, seen_poses = len(odoms), poses["r2"]
        wait_for(lambda: len(odoms) >= seen_odoms + 20 and poses["r2"] >= seen_poses + 20, what="r2 to keep posing")
        assert ros2.proc.poll() is None


@pytest.mark.integration
def test_a_node_that_fails_is_started_again_and_the_others_go_on(monkeypatch: pytest.MonkeyPatch) -> None:
    """In this process: a bug in r1's handling (injected) fails r1's node alone; it is reported and started again."""
    original = Ros2Core.on_pose

    def on_pose(self: Ros2Core, payload: bytes, now: float) -> None:
        if payload == b"boom":
            raise RuntimeError("injected bug")
        original(self, payload, now)

    monkeypatch.setattr(Ros2Core, "on_pose", on_pose)
    port = free_port()
    robots = parse_fleet({"robot": [{"id": rid, "control_port": 0, "log_port": 0} for rid in ("r1", "r2")]})
    base = Ros2Settings(zenoh=ZenohSettings(listen=[f"tcp/127.0.0.1:{port}"]))
    loop = asyncio.new_event_loop()
    stop = asyncio.Event()
    thread = threading.Thread(target=lambda: loop.run_until_complete(serve(base, robots, stop)), daemon=True)
    thread.start()

    def hub() -> zenoh.Session | None:
        try:
            return zenoh.open(client_config(port))
        except zenoh.ZError:
            return None  # not listening yet

    try:
        with wait_for(hub, what="the adapter's session to listen") as session:
            odoms: collections.Counter[str] = collections.Counter()
            errors: list[ErrorReport] = []
            session.declare_subscriber("0/*/odom/**", lambda s: odoms.update([str(s.key_expr).split("/")[1]]))
            session.declare_subscriber("fleet/r1/errors", lambda s: errors.append(decode(ErrorReport, s.payload.to_bytes())))

            def node_ids(rid: str) -> set[int]:
                found = session.liveliness().get(f"@ros2_lv/0/*/*/*/NN/%/%{rid}/blackmetal", timeout=2)
                return {int(str(r.ok.key_expr).split("/")[3]) for r in found if r.ok is not None}

            def pose_both(count: int = 5) -> None:
                for _ in range(count):
                    for rid in ("r1", "r2"):
                        session.put(f"fleet/{rid}/pose", encode(make_pose(time.time(), 1.0, 2.0, 0.5)))
                    time.sleep(0.02)

            first = wait_for(lambda: node_ids("r1"), what="r1's node")
            wait_for(lambda: (pose_both(), odoms["r1"] > 0 and odoms["r2"] > 0)[1], what="both nodes to publish /odom")
            session.put("fleet/r1/pose", b"boom")
            wait_for(lambda: any("ROS 2 node of robot 1 (id 'r1') failed" in e.reason for e in errors), what="r1's failure reported")
            seen = odoms["r2"]
            pose_both()
            wait_for(lambda: odoms["r2"] > seen, what="r2 to go on")
            again = wait_for(lambda: (ids := node_ids("r1")) and ids != first and ids, what="r1's node started again")
            assert min(again) > max(first)  # a node created again takes new ids, as in rmw_zenoh
            seen = odoms["r1"]
            wait_for(lambda: (pose_both(), odoms["r1"] > seen)[1], what="r1's node to publish /odom again")
    finally:
        loop.call_soon_threadsafe(stop.set)
        thread.join(timeout=10)
    assert not thread.is_alive()
