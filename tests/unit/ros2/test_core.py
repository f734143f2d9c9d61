"""The ROS 2 adapter, with the test playing the ROS side exactly as rmw_zenoh and zenoh-bridge-ros2dds format it.

No ROS 2 is installed here: /odom is decoded with a CDR reader written in
this file from the IDL layout (independent of rosbags), tokens are checked
against rmw_zenoh's parser rules, and commands are published as a ROS
publisher would, with and without rmw_zenoh's attachment.
"""

from __future__ import annotations

import json
import math
import struct
import time

import pytest
import zenoh
from helpers import Child, client_config, free_port, start_robot, wait_for, zenoh_connect_args

from blackmetal.robot_model import Encoders
from blackmetal.ros2.core import Ros2Core
from blackmetal.ros2.messages import RosCodec
from blackmetal.ros2.naming import (
    PARAMETER_SERVICES,
    Direction,
    NodeIdentity,
    Qos,
    attachment,
    gid_of,
    normalise_namespace,
    parse_attachment,
)
from blackmetal.ros2.options import Ros2Options
from blackmetal.ros2.ros_types import BOOL, Frames
from blackmetal.ros2.settings import diagonal_matrix
from blackmetal.schemas import ErrorReport, EStop, GatewayHealth, Keys, LinkHealth, Pose, Twist, decode, encode, make_pose

TWIST_HASH = "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
ODOM_HASH = "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0"
TF_HASH = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
TWIST_STAMPED_HASH = "RIHS01_5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64"
TWIST_KEY = f"0/cmd_vel/geometry_msgs::msg::dds_::Twist_/{TWIST_HASH}"
TWIST_STAMPED_KEY = f"0/cmd_vel/geometry_msgs::msg::dds_::TwistStamped_/{TWIST_STAMPED_HASH}"
ODOM_KEY = f"0/odom/nav_msgs::msg::dds_::Odometry_/{ODOM_HASH}"


@pytest.fixture(scope="module")
def codec() -> RosCodec:
    return RosCodec()


# ------------------------------------------------------------------ an independent CDR reader for nav_msgs/Odometry
class CdrReader:
    """Little-endian CDR as the IDL lays it out: each primitive aligned to its size, counted after the 4-byte header."""

    def __init__(self, data: bytes) -> None:
        assert data[:4] == b"\x00\x01\x00\x00", data[:4].hex()
        self.body = data[4:]
        self.pos = 0

    def _take(self, fmt: str, size: int) -> tuple[float | int, ...]:
        self.pos += -self.pos % size
        values = struct.unpack_from("<" + fmt, self.body, self.pos)
        self.pos += struct.calcsize("<" + fmt)
        return values

    def i32(self) -> int:
        return int(self._take("i", 4)[0])

    def u32(self) -> int:
        return int(self._take("I", 4)[0])

    def f64s(self, n: int) -> list[float]:
        return [float(v) for v in self._take(f"{n}d", 8)]

    def string(self) -> str:
        length = self.u32()  # includes the NUL
        text = self.body[self.pos : self.pos + length - 1].decode()
        self.pos += length
        return text

    def done(self) -> bool:
        return self.pos == len(self.body)


def ros_time(stamp: float) -> tuple[int, int]:
    """Unix seconds as builtin_interfaces/Time: whole seconds, then the nanoseconds of the remainder."""
    sec = math.floor(stamp)
    return sec, round((stamp - sec) * 1e9)


def read_odometry(data: bytes) -> dict[str, object]:
    r = CdrReader(data)
    sec, nanosec = r.i32(), r.u32()
    frame, child = r.string(), r.string()
    position, orientation, pose_cov = r.f64s(3), r.f64s(4), r.f64s(36)
    linear, angular, twist_cov = r.f64s(3), r.f64s(3), r.f64s(36)
    assert r.done(), "trailing bytes after the Odometry"
    return {
        "stamp": (sec, nanosec),
        "frame": frame,
        "child": child,
        "position": position,
        "orientation": orientation,
        "pose_cov": pose_cov,
        "linear": linear,
        "angular": angular,
        "twist_cov": twist_cov,
    }


# ------------------------------------------------------------------ formats, pure
def test_golden_twist_bytes(codec: RosCodec) -> None:
    expected = b"\x00\x01\x00\x00" + struct.pack("<6d", 0.5, 0.0, 0.0, 0.0, 0.0, 1.0)
    assert codec.encode_twist(0.5, 1.0) == expected
    twist = codec.twist(expected)
    assert (twist.linear.x, twist.angular.z) == (0.5, 1.0)


def test_type_hashes_are_computed_and_match_ros_2(codec: RosCodec) -> None:
    assert codec.type_hash("geometry_msgs/msg/Twist") == TWIST_HASH
    assert codec.type_hash("nav_msgs/msg/Odometry") == ODOM_HASH
    assert codec.type_hash("tf2_msgs/msg/TFMessage") == TF_HASH
    assert codec.type_hash("geometry_msgs/msg/TwistStamped") == TWIST_STAMPED_HASH


def test_tokens_qos_and_attachment_in_rmw_zenoh_format() -> None:
    assert Qos().keyexpr() == "::,10:,:,:,,"  # reliable, volatile, keep-last 10 against rmw_zenoh's defaults
    assert Qos(reliability=2, depth=42).keyexpr() == "2::,:,:,:,,"
    node = NodeIdentity(domain_id=0, zid="abc123", name="blackmetal", namespace=normalise_namespace("r1"))
    assert node.node_token() == "@ros2_lv/0/abc123/0/0/NN/%/%r1/blackmetal"
    token = node.entity_token(3, Direction.PUBLISH, "/r1/odom", "nav_msgs/msg/Odometry", ODOM_HASH, Qos())
    assert token == f"@ros2_lv/0/abc123/0/3/MP/%/%r1/blackmetal/%r1%odom/nav_msgs::msg::dds_::Odometry_/{ODOM_HASH}/::,10:,:,:,,"
    parts = token.split("/")
    assert len(parts) == 13 and all(parts)
    gid = gid_of(token)
    data = attachment(7, 1_700_000_000_123_456_789, gid)
    assert len(data) == 33 and data[16] == 16
    assert parse_attachment(data) == (7, 1_700_000_000_123_456_789, gid)
    with pytest.raises(ValueError):
        parse_attachment(data[:-1])


def test_covariance_diagonal() -> None:
    matrix = diagonal_matrix("1,2,3,4,5,6", "pose")
    assert [matrix[7 * i] for i in range(6)] == [1, 2, 3, 4, 5, 6] and sum(matrix) == 21
    from blackmetal.schemas import ConfigError

    for bad in ("1,2,3", "a,b,c,d,e,f", "1,2,3,4,5,nan", "1,2,3,4,5,-1"):
        with pytest.raises(ConfigError):
            diagonal_matrix(bad, "pose")


def test_help_says_each_default_once() -> None:
    import re

    from blackmetal.ros2.main import build_parser

    text = " ".join(build_parser().format_help().split())
    for option in re.findall(r"(--[a-z-]+ [A-Z]+ .*?)(?= --[a-z-]+ |$)", text):
        assert option.count("default") <= 1, option
    assert "(default /)" in text and "(default ros2)" in text and "(default 2)" in text


def test_without_the_extra_one_sentence_names_it() -> None:
    import subprocess
    import sys

    code = "import sys; sys.modules['rosbags'] = None; from blackmetal.cli import main; sys.exit(main(sys.argv[1:]))"
    for args in (["ros2", "-l", "tcp/127.0.0.1:0"], ["up", "--ros2"]):
        proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2, proc.stderr
        assert proc.stderr.strip().count("\n") == 0 and "pip install 'blackmetal[ros2]'" in proc.stderr, proc.stderr
        assert "Traceback" not in proc.stderr


# ------------------------------------------------------------------ the adapter's core, no Zenoh, on a fake clock
class Recorder:
    def __init__(self) -> None:
        self.ros_out: list[tuple[str, bytes]] = []
        self.forwarded: list[tuple[str, bytes]] = []
        self.errors: list[ErrorReport] = []

    def ros(self, topic: str, cdr: bytes) -> None:
        self.ros_out.append((topic, cdr))

    def blackmetal(self, key: str, payload: bytes) -> None:
        self.forwarded.append((key, payload))

    def error(self, message: ErrorReport) -> None:
        self.errors.append(message)


def make_adapter(codec: RosCodec) -> tuple[Ros2Core, Recorder]:
    out = Recorder()
    options = Ros2Options(
        frames=Frames(),
        pose_covariance=diagonal_matrix("0.1,0.2,0,0,0,0.3", "p"),
        twist_covariance=diagonal_matrix("0.01,0,0,0,0,0.02", "t"),
        publish_tf=True,
        joint_names=("left_wheel_joint", "right_wheel_joint"),
        wheel_radius=0.1,
        encoders=Encoders(),
        data_keys={"cmd_vel": TWIST_KEY, "cmd_vel_stamped": "0/cmd_vel/geometry_msgs::msg::dds_::TwistStamped_/RIHS01_stamped"},
    )
    return Ros2Core(options, Keys(), out, codec, wallclock=lambda: 1_700_000_000.0), out


def test_bad_cmd_vel_is_reported_and_never_forwarded(codec: RosCodec) -> None:
    adapter, out = make_adapter(codec)
    good = codec.encode_twist(0.2, 0.1)
    bad = {
        "truncated": good[:20],
        "wrong header": b"\x07\x07\x00\x00" + good[4:],
        "empty": b"",
        "NaN": b"\x00\x01\x00\x00" + struct.pack("<6d", math.nan, 0, 0, 0, 0, 0),
        "infinite": b"\x00\x01\x00\x00" + struct.pack("<6d", 0, 0, 0, 0, 0, math.inf),
        "a JSON twist": b'{"linear":{"x":0.2}}',
        "too long": good + b"\x00" * 64,
    }
    for payload in bad.values():
        adapter.on_cmd_vel(payload, now=1.0)
    assert out.forwarded == []
    assert len(out.errors) == len(bad)
    reasons = [e.reason for e in out.errors]
    assert all(e.key == TWIST_KEY and e.source == "ros2" for e in out.errors)
    assert "encapsulation header 07 07 00 00" in reasons[1]
    assert "linear.x must be finite" in reasons[3] and "angular.z must be finite" in reasons[4]
    adapter.on_cmd_vel(good, now=1.0)
    assert [key for key, _ in out.forwarded] == ["robot/cmd_vel/ros2"]  # the command source ros2
    assert decode(Twist, out.forwarded[0][1]).linear.x == 0.2


def test_twist_stamped_and_estop(codec: RosCodec) -> None:
    adapter, out = make_adapter(codec)
    adapter.on_cmd_vel(codec.encode_twist(0.3, -0.4, stamp=1_699_999_999.8, frame_id="base_link"), now=1.0, stamped=True)
    adapter.on_cmd_vel(codec.encode_twist(0.3, -0.4), now=1.0, stamped=True)  # a plain Twist on the TwistStamped key
    assert len(out.forwarded) == 1 and len(out.errors) == 1
    assert out.errors[0].key.endswith("TwistStamped_/RIHS01_stamped")
    twist = decode(Twist, out.forwarded[0][1])
    assert (twist.linear.x, twist.angular.z) == (0.3, -0.4)
    adapter.on_estop(codec.encode(BOOL, data=True), now=1.0)
    adapter.on_estop(b"\x00\x01\x00\x00", now=1.0)  # no data byte
    assert decode(EStop, out.forwarded[-1][1]).engaged is True and out.forwarded[-1][0] == "robot/estop"
    assert len(out.errors) == 2


def test_twist_and_twist_stamped_both_drive_and_a_stale_stamped_command_is_refused(codec: RosCodec) -> None:
    """The wall clock is 1_700_000_000.0; the gateway's command timeout 0.5 s until its health says otherwise."""
    adapter, out = make_adapter(codec)
    adapter.on_cmd_vel(codec.encode_twist(0.1, 0.0), now=1.0)  # Twist
    adapter.on_cmd_vel(codec.encode_twist(0.2, 0.0, stamp=1_699_999_999.6), now=1.0, stamped=True)  # 0.4 s old: taken
    adapter.on_cmd_vel(codec.encode_twist(0.3, 0.0, stamp=0.0), now=1.0, stamped=True)  # a zero stamp means now
    adapter.on_cmd_vel(codec.encode_twist(0.4, 0.0, stamp=1_699_999_999.2), now=1.0, stamped=True)  # 0.8 s old: refused
    assert [decode(Twist, payload).linear.x for _, payload in out.forwarded] == [0.1, 0.2, 0.3]
    (stale,) = out.errors
    assert "0.800 s old" in stale.reason and "command timeout 0.5 s" in stale.reason
    health = GatewayHealth(stamp=1_700_000_000.0, control=LinkHealth(state="connected"), log=LinkHealth(state="connected"), cmd_timeout=1.0)
    adapter.on_health(encode(health), now=1.0)  # the gateway's own timeout counts once it is known
    adapter.on_cmd_vel(codec.encode_twist(0.4, 0.0, stamp=1_699_999_999.2), now=1.0, stamped=True)
    assert decode(Twist, out.forwarded[-1][1]).linear.x == 0.4


def test_pose_becomes_odom_and_tf_with_the_same_stamp(codec: RosCodec) -> None:
    adapter, out = make_adapter(codec)
    pose = make_pose(1_700_000_000.25, 1.5, -0.5, 0.7, v=0.3, w=0.1)
    adapter.on_pose(encode(pose), now=1.0)
    adapter.on_pose(b'{"x": "nope"}', now=1.0)
    assert [t for t, _ in out.ros_out] == ["odom", "tf"] and len(out.errors) == 1
    odom = read_odometry(out.ros_out[0][1])
    assert odom["frame"] == "odom" and odom["child"] == "base_footprint"
    assert odom["stamp"] == (1_700_000_000, 250_000_000)
    assert odom["position"] == [1.5, -0.5, 0.0]
    assert odom["orientation"] == pytest.approx([0.0, 0.0, math.sin(0.35), math.cos(0.35)])
    assert odom["linear"] == [0.3, 0.0, 0.0] and odom["angular"] == [0.0, 0.0, 0.1]
    assert odom["pose_cov"][0] == 0.1 and odom["pose_cov"][7] == 0.2 and odom["pose_cov"][35] == 0.3
    assert odom["twist_cov"][35] == 0.02
    tf = codec.decode(out.ros_out[1][1], "tf2_msgs/msg/TFMessage").transforms[0]
    assert (tf.header.stamp.sec, tf.header.stamp.nanosec) == (1_700_000_000, 250_000_000)
    assert (tf.header.frame_id, tf.child_frame_id, tf.transform.translation.x) == ("odom", "base_footprint", 1.5)


def test_joint_states_integrate_the_wheels(codec: RosCodec) -> None:
    adapter, out = make_adapter(codec)
    enc = Encoders()
    left, right = enc.to_impulses(0.2, 0.2)  # both wheels forward at 0.2 m/s
    for i in range(11):  # 1 s at 10 Hz
        adapter.on_impulses(encode_impulses(i, 100.0 + 0.1 * i, round(left), round(right)), now=1.0)
    adapter.on_impulses(encode_impulses(11, 105.0, round(left), round(right)), now=1.0)  # after a 3.9 s gap: not integrated
    state = codec.decode(out.ros_out[-1][1], "sensor_msgs/msg/JointState")
    assert list(state.name) == ["left_wheel_joint", "right_wheel_joint"]
    assert state.position == pytest.approx([2.0, 2.0], rel=3e-3)  # 0.2 m / 0.1 m radius (impulses are whole numbers)
    assert state.velocity == pytest.approx([2.0, 2.0], rel=3e-3)


def test_a_flood_of_bad_input_is_summarised_by_the_cores_tick(codec: RosCodec) -> None:
    adapter, out = make_adapter(codec)
    assert adapter.reporter.next_deadline() == math.inf  # nothing suppressed: no summary due
    adapter.tick(9.5)  # the first diagnostics; the next are due at 10.5
    for _ in range(50):  # one instant: the burst is published, the rest suppressed
        adapter.on_cmd_vel(b"", now=10.0)
    published = len(out.errors)
    assert 0 < published < 50 and out.forwarded == []
    deadline = adapter.reporter.next_deadline()
    assert 10.0 < deadline < math.inf and adapter.next_deadline() == min(deadline, 10.5)
    adapter.tick(deadline - 0.01)  # not yet due: nothing
    assert len(out.errors) == published
    adapter.tick(deadline)
    summary = out.errors[-1]
    assert len(out.errors) == published + 1 and summary.suppressed == 50 - published
    assert summary.key == TWIST_KEY and summary.source == "ros2" and "rate-limited" in summary.reason
    assert adapter.reporter.next_deadline() == math.inf


def encode_impulses(seq: int, stamp: float, left: int, right: int) -> bytes:
    return json.dumps({"seq": seq, "stamp": stamp, "mono": stamp, "left": left, "right": right}).encode()


# ------------------------------------------------------------------ on Zenoh, with the simulator, gateway and odometry
def truth(session: zenoh.Session) -> Pose:
    replies = [r for r in session.get("robot/sim/truth", timeout=5) if r.ok is not None]
    assert replies, "no answer from the simulator"
    return decode(Pose, replies[0].ok.payload.to_bytes())


def drives(session: zenoh.Session, key: str, payload: bytes, with_attachment: bool = False) -> float:
    """Publish ``payload`` on ``key`` at 10 Hz for 1.5 s as a ROS publisher would; how far the true robot moved."""
    start = truth(session)
    gid = gid_of("@ros2_lv/0/test/0/1/MP/%/%/teleop/%cmd_vel")
    for seq in range(1, 16):
        extra = {"attachment": attachment(seq, time.time_ns(), gid)} if with_attachment else {}
        session.put(key, payload, **extra)
        time.sleep(0.1)
    end = truth(session)
    return math.hypot(end.x - start.x, end.y - start.y)


@pytest.mark.integration
def test_rmw_zenoh_flavour_end_to_end(children: list[Child], codec: RosCodec) -> None:
    zport = free_port()
    start_robot(children, zport, gateway_args=("--poll-hz", "50"))
    ros2 = Child(["-m", "blackmetal.ros2", *zenoh_connect_args(zport)])
    children.append(ros2)
    ready = ros2.ready()
    assert ready["keys"]["cmd_vel"] == TWIST_KEY and ready["keys"]["odom"] == ODOM_KEY
    with zenoh.open(client_config(zport)) as session:
        poses: dict[tuple[int, int], Pose] = {}
        odoms: list[tuple[bytes, bytes | None]] = []
        errors: list[ErrorReport] = []
        session.declare_subscriber("robot/pose", lambda s: poses.__setitem__(ros_time((p := decode(Pose, s.payload.to_bytes())).stamp), p))
        session.declare_subscriber(
            ODOM_KEY, lambda s: odoms.append((s.payload.to_bytes(), None if s.attachment is None else s.attachment.to_bytes()))
        )
        session.declare_subscriber("robot/errors", lambda s: errors.append(decode(ErrorReport, s.payload.to_bytes())))
        wait_for(lambda: len(odoms) >= 20, what="/odom samples")

        # /odom is the pose on robot/pose, field for field
        matched = 0
        for payload, att in list(odoms):
            odom = read_odometry(payload)
            pose = poses.get(odom["stamp"])  # type: ignore[call-overload]
            if pose is None:
                continue  # published before our pose subscription was in place
            matched += 1
            assert odom["frame"] == "odom" and odom["child"] == "base_footprint"
            assert odom["position"][:2] == [pose.x, pose.y]
            q = pose.orientation
            assert odom["orientation"] == [q.x, q.y, q.z, q.w]
            assert att is not None and len(att) == 33
        assert matched >= 10
        sequences = [parse_attachment(att)[0] for _, att in odoms if att is not None]
        assert sequences == sorted(sequences) and len(set(sequences)) == len(sequences)

        # the ROS graph: one node token, one token per topic and service, each as rmw_zenoh's parser splits it
        tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**", timeout=5) if r.ok is not None]
        nodes = [t for t in tokens if t.split("/")[5] == "NN"]
        entities = [t for t in tokens if t.split("/")[5] in ("MP", "MS", "SS")]
        assert len(nodes) == 1 and nodes[0].split("/")[6:] == ["%", "%", "blackmetal"] and len(nodes[0].split("/")) == 9
        # /cmd_vel twice: Twist and TwistStamped; the robot model's two; /parameter_events and six parameter services;
        # navigate_to_pose's three services and two topics, /goal_pose and /initialpose
        assert len(entities) == len(tokens) - 1 == 25
        for token in tokens:
            assert all(token.split("/")), token
        for token in entities:
            assert len(token.split("/")) == 13, token
        published = {t.split("/")[9] for t in entities if t.split("/")[5] == "MP"}
        subscribed = {t.split("/")[9] for t in entities if t.split("/")[5] == "MS"}
        served = {t.split("/")[9] for t in entities if t.split("/")[5] == "SS"}
        assert published == {"%odom", "%tf", "%joint_states", "%diagnostics", "%robot_description", "%tf_static", "%parameter_events"} | {
            "%navigate_to_pose%_action%feedback",
            "%navigate_to_pose%_action%status",
        }
        assert subscribed == {"%cmd_vel", "%estop", "%goal_pose", "%initialpose"}
        cmd_vel_types = sorted(t.split("/")[10] for t in entities if t.split("/")[9] == "%cmd_vel")
        assert cmd_vel_types == ["geometry_msgs::msg::dds_::TwistStamped_", "geometry_msgs::msg::dds_::Twist_"]
        params = {f"%blackmetal%{name}" for name in PARAMETER_SERVICES}  # node-private, as rclcpp's ~/list_parameters
        assert served == {"%set_estop", "%reset_odometry"} | params | {
            f"%navigate_to_pose%_action%{n}" for n in ("send_goal", "cancel_goal", "get_result")
        }

        # /cmd_vel from a ROS publisher drives the robot, with or without the attachment
        twist = codec.encode_twist(0.3, 0.0)
        assert drives(session, TWIST_KEY, twist, with_attachment=True) > 0.15
        # and a TwistStamped on the same topic, as Nav2 publishes it from Kilted on (a zero stamp means now)
        assert drives(session, TWIST_STAMPED_KEY, codec.encode_twist(0.3, 0.0, stamp=0.0), with_attachment=True) > 0.15
        assert drives(session, TWIST_KEY, twist) > 0.15

        # a bad /cmd_vel is reported and never reaches the gateway
        forwarded: list[bytes] = []
        session.declare_subscriber("robot/cmd_vel/**", lambda s: forwarded.append(s.payload.to_bytes()))
        session.declare_subscriber("robot/cmd_vel", lambda s: forwarded.append(s.payload.to_bytes()))
        time.sleep(0.3)  # let the subscription propagate; then nothing valid is sent
        for n, bad in enumerate([b"\x00\x01\x00\x00" + struct.pack("<6d", math.nan, 0, 0, 0, 0, 0), twist[:30]], start=1):
            session.put(TWIST_KEY, bad)  # one at a time: a newer command supersedes one not yet handled
            wait_for(lambda n=n: len([e for e in errors if e.key == TWIST_KEY]) >= n, what=f"error report {n} for a bad /cmd_vel")
        assert forwarded == []
        assert ros2.proc.poll() is None


@pytest.mark.integration
def test_bridge_flavour_and_namespaces(children: list[Child], codec: RosCodec) -> None:
    zport = free_port()
    start_robot(children, zport, gateway_args=("--poll-hz", "50"))
    bridge = Child(["-m", "blackmetal", "ros2", "--flavor", "bridge", *zenoh_connect_args(zport)])
    bridge_ns = Child(["-m", "blackmetal", "ros2", "--flavor", "bridge", "--namespace", "r1", *zenoh_connect_args(zport)])
    rmw_ns = Child(["-m", "blackmetal", "ros2", "--namespace", "r1", "--no-tf", *zenoh_connect_args(zport)])
    children.extend([bridge, bridge_ns, rmw_ns])
    assert bridge.ready()["keys"]["cmd_vel"] == "cmd_vel"
    assert bridge_ns.ready()["keys"]["cmd_vel"] == "r1/cmd_vel"
    rmw_keys = rmw_ns.ready()["keys"]
    assert rmw_keys["cmd_vel"] == f"0/r1/cmd_vel/geometry_msgs::msg::dds_::Twist_/{TWIST_HASH}"
    assert "tf" not in rmw_keys
    with zenoh.open(client_config(zport)) as session:
        odoms: list[bytes | None] = []
        session.declare_subscriber("odom", lambda s: odoms.append(None if s.attachment is None else s.attachment.to_bytes()))
        wait_for(lambda: len(odoms) >= 5, what="/odom from the bridge flavour")
        assert set(odoms) == {None}, "the bridge flavour carries no attachment"
        twist = codec.encode_twist(0.3, 0.0)
        assert drives(session, "cmd_vel", twist) > 0.15
        assert drives(session, "r1/cmd_vel", twist) > 0.15
        assert drives(session, rmw_keys["cmd_vel"], twist) > 0.15
        tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**", timeout=5) if r.ok is not None]
        # node + 9 topics + 8 services + the action's 5 and RViz's 2 pose topics, none from the bridges
        assert len(tokens) == 25 and all(t.split("/")[7] == "%r1" for t in tokens)
        names = {t.split("/")[9] for t in tokens if len(t.split("/")) == 13}
        assert {"%r1%cmd_vel", "%diagnostics", "%r1%set_estop"} <= names  # /diagnostics is absolute, services relative
