"""The ROS 2 adapter against independent rmw_zenoh clients, on every distro it speaks (issue #28).

* Jazzy: **zenoh-ros2-sdk** (ROBOTIS, from PyPI), installed by a session
  fixture in its own virtualenv under a temporary directory and driven as a
  subprocess (``tests/ros2_sdk_client.py``), so its dependencies never mix
  with ours. It computes its own type hashes and writes its own keys,
  tokens and attachments. Its message definitions are written by the
  fixture from rosbags' ROS 2 Jazzy type store (the SDK would clone them from
  GitHub); the SDK's keys are held to the RIHS01 hashes of ROS 2 Jazzy itself.
* Humble: a client written here from rmw_zenoh's Humble sources (release
  0.1.9: ``TypeHashNotSupported`` in keys and tokens, the 33-byte attachment
  of ``attachment_helpers.cpp``), not from the adapter's naming module.

Every process is a client of a router started with rmw_zenoh's router
config, as the ROS side deploys it; the SDK is a peer of it.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import struct
import subprocess
import time
import venv
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import xxhash
import zenoh
from helpers import Child, client_config, free_port, wait_for
from unit.ros2.test_core import ODOM_HASH, TWIST_HASH, TWIST_STAMPED_HASH, read_odometry
from unit.tools.test_urdf import check_urdf

from blackmetal import robot_model as model
from blackmetal.schemas import Pose, decode
from blackmetal.wire import CommandCode

pytestmark = pytest.mark.integration

ROS2_DEPLOY = Path(__file__).resolve().parents[2] / "deploy" / "ros2"
CLIENT = Path(__file__).resolve().parents[1] / "ros2_sdk_client.py"
#: The types the SDK client uses, with their dependencies written beside them.
SDK_TYPES = (
    "geometry_msgs/msg/Twist",
    "geometry_msgs/msg/TwistStamped",
    "nav_msgs/msg/Odometry",
    "std_msgs/msg/String",
    "tf2_msgs/msg/TFMessage",
    "sensor_msgs/msg/JointState",
    "rcl_interfaces/msg/Parameter",
    "rcl_interfaces/msg/ParameterValue",
    "rcl_interfaces/msg/ParameterDescriptor",
    "rcl_interfaces/msg/SetParametersResult",
    "rcl_interfaces/msg/ListParametersResult",
    "rcl_interfaces/msg/ParameterEvent",
)
#: Genuine .srv files (tests/ros2_interfaces/README.md says where from), copied into the SDK's interfaces directory.
VENDORED = Path(__file__).resolve().parents[1] / "ros2_interfaces"
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"  # std_msgs/String, ROS 2 Jazzy


# ------------------------------------------------------------------ the SDK in its own virtualenv
@pytest.fixture(scope="session")
def sdk_python(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A virtualenv with zenoh-ros2-sdk from PyPI; its interpreter. Skipped (one sentence) only when PyPI cannot be reached."""
    root = tmp_path_factory.mktemp("zenoh-ros2-sdk")
    venv.EnvBuilder(with_pip=True).create(root / "venv")
    python = str(root / "venv" / "bin" / "python")
    pip = [python, "-m", "pip", "--disable-pip-version-check", "-q"]
    installed = subprocess.run([*pip, "install", "zenoh-ros2-sdk"], capture_output=True, text=True, timeout=600)
    if installed.returncode != 0:
        probe = subprocess.run(
            [*pip, "download", "--no-deps", "-d", str(root / "probe"), "zenoh-ros2-sdk"], capture_output=True, timeout=300
        )
        if probe.returncode != 0:
            pytest.skip("PyPI cannot be reached, so zenoh-ros2-sdk cannot be installed for the independent-client tests.")
        raise AssertionError(f"pip install zenoh-ros2-sdk failed:\n{installed.stdout}\n{installed.stderr}")
    return python


@pytest.fixture(scope="session")
def interfaces(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``<pkg>/msg/<Type>.msg`` for the SDK's registry, written from rosbags' ROS 2 Jazzy store (fields, no comments)."""
    from rosbags.typesys import Stores, get_typestore
    from rosbags.typesys.base import Nodetype

    store = get_typestore(Stores.ROS2_JAZZY)
    root = tmp_path_factory.mktemp("ros2_interfaces")

    def spelled(desc: Any) -> str:
        kind, rest = desc
        if kind == Nodetype.BASE:
            return f"string<={rest[1]}" if rest[0] == "string" and rest[1] else str(rest[0])
        if kind == Nodetype.NAME:
            package, _, name = rest.split("/")
            return f"{package}/{name}"
        size = rest[1] if kind == Nodetype.ARRAY else (f"<={rest[1]}" if rest[1] else "")
        return f"{spelled(rest[0])}[{size}]"

    def write(typename: str) -> None:
        path = root.joinpath(*typename.split("/")).with_suffix(".msg")
        if path.exists():
            return
        consts, fields = store.fielddefs[typename]
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("".join(f"{t} {n}={v}\n" for n, t, v in consts) + "".join(f"{spelled(d)} {n}\n" for n, d in fields))
        for _, desc in fields:
            while desc[0] in (Nodetype.ARRAY, Nodetype.SEQUENCE):
                desc = desc[1][0]
            if desc[0] == Nodetype.NAME:
                write(desc[1])

    for typename in SDK_TYPES:
        write(typename)
    for srv in VENDORED.glob("*/srv/*.srv"):
        target = root / srv.relative_to(VENDORED)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(srv, target)
    return root


class SdkNode:
    """The SDK client process: one JSON command a line, one JSON answer a line."""

    def __init__(self, python: str, port: int, interfaces: Path) -> None:
        env = {**os.environ, "ZENOH_CONFIG_OVERRIDE": 'listen/endpoints=["tcp/127.0.0.1:0"]', "ROS_DOMAIN_ID": "0"}
        env.pop("PYTHONPATH", None)
        self.proc = subprocess.Popen(
            [python, str(CLIENT), str(port), str(interfaces)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        assert self._line(60) == {"ready": True}

    def _line(self, timeout: float) -> dict[str, Any]:
        import selectors

        assert self.proc.stdout is not None
        with selectors.DefaultSelector() as sel:
            sel.register(self.proc.stdout, selectors.EVENT_READ)
            if not sel.select(timeout):
                raise AssertionError(f"the SDK client said nothing in {timeout:.0f} s")
        line = self.proc.stdout.readline()
        if not line:
            err = self.proc.stderr.read() if self.proc.stderr else ""
            raise AssertionError(f"the SDK client ended (exit {self.proc.wait(5)}):\n{err[-3000:]}")
        return dict(json.loads(line))

    def ask(self, timeout: float = 60, **command: Any) -> dict[str, Any]:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(command) + "\n")
        self.proc.stdin.flush()
        answer = self._line(timeout)
        assert "error" not in answer, answer
        return answer

    def received(self, topic: str, count: int = 1, what: str = "") -> dict[str, Any]:
        return dict(wait_for(lambda: (r := self.ask(op="received", topic=topic))["count"] >= count and r, what=what or topic))

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.ask(op="quit", timeout=5)
            except (AssertionError, BrokenPipeError, OSError):
                pass
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)


@pytest.fixture
def sdk(sdk_python: str, interfaces: Path) -> Iterator[Any]:
    nodes: list[SdkNode] = []

    def start(port: int) -> SdkNode:
        node = SdkNode(sdk_python, port, interfaces)
        nodes.append(node)
        return node

    yield start
    for node in nodes:
        node.close()


# ------------------------------------------------------------------ the ROS side's router, and the robot
def ros_graph(children: list[Child], *up_args: str) -> int:
    """rmw_zenohd (rmw_zenoh's router config) on a free port and ``blackmetal up --ros2 ARGS`` as its client; the port."""
    port = free_port()
    router = Child(["-m", "blackmetal", "router", "-c", str(ROS2_DEPLOY / "rmw_zenohd.json5"), "-l", f"tcp/127.0.0.1:{port}"])
    children.append(router)
    router.ready()
    up = Child(["-m", "blackmetal", "up", "--ros2", *up_args, "-e", f"tcp/127.0.0.1:{port}"])
    children.append(up)
    up.ready(timeout=90)
    return port


def truth(session: zenoh.Session, key: str = "robot/sim/truth") -> Pose:
    replies = [r for r in session.get(key, timeout=5) if r.ok is not None]
    assert replies, f"no answer on {key}"
    return decode(Pose, replies[0].ok.payload.to_bytes())


def moved(session: zenoh.Session, drive: Any, key: str = "robot/sim/truth") -> float:
    """How far the true robot moved while ``drive()`` ran and it came to rest after (m)."""
    start = truth(session, key)
    drive()
    wait_for(lambda: abs(truth(session, key).v) < 1e-9, what="the robot to stop after its commands")
    end = truth(session, key)
    return math.hypot(end.x - start.x, end.y - start.y)


# ------------------------------------------------------------------ a Humble client, from rmw_zenoh 0.1.9's sources
class HumbleClient:
    """What a ROS 2 Humble node under rmw_zenoh (0.1.2 and later) does on the wire, written from its sources.

    ``rmw_publisher_data.cpp``/``rmw_subscription_data.cpp``: ``TypeHashNotSupported`` where later distros
    put the RIHS01 hash, in the key and in the token; ``liveliness_utils.cpp``: the token
    ``@ros2_lv/<domain>/<zid>/<nid>/<id>/<MP|MS>/<enclave>/<ns>/<node>/<topic>/<type>/<hash>/<qos>`` with ``/`` -> ``%``,
    its GID the XXH3-128 of the token; ``attachment_helpers.cpp``: int64 sequence, int64 timestamp, then the
    16-byte GID as ``zenoh::ext::Serializer`` writes a ``std::array`` (a length byte, 16, then the bytes).
    """

    HASH = "TypeHashNotSupported"
    QOS = "::,10:,:,:,,"  # reliable, volatile, keep-last 10 against rmw_zenoh's defaults

    def __init__(self, session: zenoh.Session, node: str = "humble_teleop") -> None:
        self.session = session
        self.zid = str(session.zid())
        self.node = node
        self.tokens = [session.liveliness().declare_token(f"@ros2_lv/0/{self.zid}/0/0/NN/%/%/{node}")]
        self.next_id = 1

    def key(self, topic: str, dds_type: str) -> str:
        return f"0/{topic.strip('/')}/{dds_type}/{self.HASH}"

    def entity(self, kind: str, topic: str, dds_type: str) -> bytes:
        token = f"@ros2_lv/0/{self.zid}/0/{self.next_id}/{kind}/%/%/{self.node}/{topic.replace('/', '%')}/{dds_type}/{self.HASH}/{self.QOS}"
        self.next_id += 1
        self.tokens.append(self.session.liveliness().declare_token(token))
        return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(16, "little")

    def subscribe_odom(self) -> list[tuple[bytes, bytes | None]]:
        dds = "nav_msgs::msg::dds_::Odometry_"
        self.entity("MS", "/odom", dds)
        got: list[tuple[bytes, bytes | None]] = []
        self.session.declare_subscriber(
            self.key("/odom", dds), lambda s: got.append((s.payload.to_bytes(), None if s.attachment is None else s.attachment.to_bytes()))
        )
        return got

    def drive(self, linear_x: float, seconds: float = 1.5) -> None:
        dds = "geometry_msgs::msg::dds_::Twist_"
        gid = self.entity("MP", "/cmd_vel", dds)
        publisher = self.session.declare_publisher(self.key("/cmd_vel", dds))
        time.sleep(0.3)
        twist = b"\x00\x01\x00\x00" + struct.pack("<6d", linear_x, 0, 0, 0, 0, 0)
        for sequence in range(1, round(seconds * 10) + 1):
            publisher.put(twist, attachment=struct.pack("<qqB", sequence, time.time_ns(), 16) + gid)
            time.sleep(0.1)
        publisher.undeclare()

    def list_parameters(self, node: str = "/blackmetal") -> list[str]:
        """``ros2 param list``'s call on Humble (``rmw_client_data.cpp``: a get on the service key with the request
        and the client's attachment); the names, read from the CDR by hand (ListParametersResult: string[] names,
        string[] prefixes)."""
        dds = "rcl_interfaces::srv::dds_::ListParameters_"
        gid = self.entity("SC", f"{node}/list_parameters", dds)
        request = b"\x00\x01\x00\x00" + struct.pack("<I", 0) + b"\x00" * 4 + struct.pack("<Q", 0)  # no prefixes, depth 0
        replies = list(self.session.get(self.key(f"{node}/list_parameters", dds), payload=request, timeout=5,
                                        attachment=struct.pack("<qqB", 1, time.time_ns(), 16) + gid,
                                        target=zenoh.QueryTarget.ALL_COMPLETE))  # fmt: skip
        oks = [r.ok for r in replies if r.ok is not None]
        if not oks:
            return []  # not served yet
        (reply,) = oks
        assert reply.attachment is not None and struct.unpack_from("<q", reply.attachment.to_bytes())[0] == 1  # our sequence
        body, pos, names = reply.payload.to_bytes()[4:], 4, []
        for _ in range(struct.unpack_from("<I", body, 0)[0]):
            pos += -pos % 4
            (length,) = struct.unpack_from("<I", body, pos)
            names.append(body[pos + 4 : pos + 4 + length - 1].decode())
            pos += 4 + length
        return names

    def close(self) -> None:
        for token in self.tokens:
            token.undeclare()


def assert_humble_drives_and_sees_odom(session: zenoh.Session) -> None:
    humble = HumbleClient(session)
    try:
        odoms = humble.subscribe_odom()
        wait_for(lambda: len(odoms) >= 10, what="/odom at the Humble client (TypeHashNotSupported key)")
        payload, attachment = odoms[-1]
        odom = read_odometry(payload)
        assert (odom["frame"], odom["child"]) == ("odom", "base_footprint")
        assert attachment is not None and len(attachment) == 33 and attachment[16] == 16
        assert moved(session, lambda: humble.drive(0.3)) > 0.15
    finally:
        humble.close()


def tokens(session: zenoh.Session) -> list[str]:
    return [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**", timeout=5) if r.ok is not None]


# ------------------------------------------------------------------ the tests
def test_jazzy_sdk_drives_with_twist_and_twist_stamped_and_reads_odom(children: list[Child], sdk: Any) -> None:
    port = ros_graph(children, "--distro", "jazzy")
    node = sdk(port)
    key = node.ask(op="subscribe", topic="/odom", type="nav_msgs/msg/Odometry")["key"]
    assert key == f"0/odom/nav_msgs::msg::dds_::Odometry_/{ODOM_HASH}"  # the SDK's own hash is ROS 2 Jazzy's
    odom = node.received("/odom", 20, "/odom at the SDK")["last"]
    assert (odom["header"]["frame_id"], odom["child_frame_id"]) == ("odom", "base_footprint")
    with zenoh.open(client_config(port)) as session:
        twist = {"linear": {"x": 0.3}}
        sent: dict[str, Any] = {}

        def drive(ros_type: str, message: dict[str, Any], **extra: Any) -> None:
            sent.update(node.ask(op="publish", topic="/cmd_vel", type=ros_type, message=message, rate_hz=10, duration_s=1.5, **extra))

        assert moved(session, lambda: drive("geometry_msgs/msg/Twist", twist)) > 0.15
        assert sent["key"] == f"0/cmd_vel/geometry_msgs::msg::dds_::Twist_/{TWIST_HASH}"
        stamped = {"header": {"frame_id": "base_link"}, "twist": twist}
        assert moved(session, lambda: drive("geometry_msgs/msg/TwistStamped", stamped, stamp="now")) > 0.15
        assert sent["key"] == f"0/cmd_vel/geometry_msgs::msg::dds_::TwistStamped_/{TWIST_STAMPED_HASH}"
        seen = node.ask(op="received", topic="/odom")["last"]
        assert seen["pose"]["pose"]["position"]["x"] > 0.3  # /odom followed the robot


def test_a_late_sdk_subscriber_gets_the_robot_description_and_tf_static(children: list[Child], sdk: Any, tmp_path: Path) -> None:
    port = ros_graph(children)
    node = sdk(port)
    node.ask(op="subscribe", topic="/joint_states", type="sensor_msgs/msg/JointState")
    joint_names = node.received("/joint_states", 1, "/joint_states")["last"]["name"]
    time.sleep(5.0)  # joins 5 s after the node published its description once
    key = node.ask(op="subscribe", topic="/robot_description", type="std_msgs/msg/String", transient_local=True)["key"]
    assert key == f"0/robot_description/std_msgs::msg::dds_::String_/{STRING_HASH}"
    node.ask(op="subscribe", topic="/tf_static", type="tf2_msgs/msg/TFMessage", transient_local=True)
    description = node.received("/robot_description", 1, "the late subscriber's /robot_description")
    print(f"late /robot_description after {1000 * description['first_after_s']:.0f} ms")
    urdf = description["last"]["data"]
    path = tmp_path / "robot_description.urdf"
    path.write_text(urdf)
    checked = subprocess.run([check_urdf(), str(path)], capture_output=True, text=True, timeout=60)
    assert checked.returncode == 0 and "root Link: base_footprint" in checked.stdout, checked.stdout + checked.stderr
    robot = ET.fromstring(urdf)
    moving = {j.get("name"): j for j in robot.iter("joint") if j.get("type") == "continuous"}
    assert list(moving) == joint_names == ["left_wheel_joint", "right_wheel_joint"]
    ys = [float(j.find("origin").get("xyz").split()[1]) for j in moving.values()]  # type: ignore[union-attr]
    assert ys[0] - ys[1] == pytest.approx(model.WHEEL_SEPARATION)
    assert {float(c.get("radius") or 0) for c in robot.iter("cylinder")} == {model.WHEEL_RADIUS}
    static = node.received("/tf_static", 1, "the late subscriber's /tf_static")["last"]["transforms"]
    pairs = {(t["header"]["frame_id"], t["child_frame_id"]) for t in static}
    assert pairs == {("base_footprint", "base_link"), ("base_link", "caster")}
    base = next(t for t in static if t["child_frame_id"] == "base_link")
    assert base["transform"]["translation"]["z"] == pytest.approx(model.WHEEL_RADIUS)


def test_humble_client_reads_odom_and_drives(children: list[Child]) -> None:
    port = ros_graph(children, "--distro", "humble")
    with zenoh.open(client_config(port)) as session:
        graph = wait_for(lambda: [t for t in tokens(session) if "/blackmetal/" in t], what="the Humble node's tokens")
        assert all(t.split("/")[11] == "TypeHashNotSupported" for t in graph if len(t.split("/")) == 13)
        assert not any("RIHS01_" in t for t in tokens(session))  # a Humble node only
        assert_humble_drives_and_sees_odom(session)
        humble = HumbleClient(session, node="humble_param_client")
        try:  # `ros2 param list /blackmetal` on Humble: the gateway's parameters (its table reached the node first)
            names = wait_for(lambda: humble.list_parameters() or None, what="the gateway's parameters through the Humble node")
            assert {"max_wheel_speed", "cmd_timeout", "wheel_radius"} <= set(names)
        finally:
            humble.close()


def test_humble_and_jazzy_at_once_both_drive_and_read_odom_at_the_pose_rate(children: list[Child], sdk: Any) -> None:
    port = ros_graph(children, "--distro", "humble,jazzy")
    node = sdk(port)
    node.ask(op="subscribe", topic="/odom", type="nav_msgs/msg/Odometry")
    with zenoh.open(client_config(port)) as session:
        nodes = wait_for(lambda: len(n := [t for t in tokens(session) if t.split("/")[5] == "NN" and t.endswith("/blackmetal")]) == 2 and n)
        assert len({t.split("/")[3] for t in nodes}) == 2  # two nodes, one per distro
        # the rate: every pose becomes an /odom, a /tf and (every impulse sample) a /joint_states on each distro
        counts: dict[str, int] = {}

        def count(name: str) -> Any:
            return lambda _sample: counts.__setitem__(name, counts.get(name, 0) + 1)

        subscribers = [session.declare_subscriber("robot/pose", count("pose"))]
        for distro, hash_part in (("humble", "TypeHashNotSupported"), ("jazzy", "RIHS01_$*")):
            for topic in ("odom", "tf", "joint_states"):
                subscribers.append(session.declare_subscriber(f"0/{topic}/*/{hash_part}", count(f"{distro} {topic}")))
        time.sleep(0.5)
        counts.clear()
        time.sleep(4.0)
        snapshot = dict(counts)
        for s in subscribers:
            s.undeclare()
        print("samples in 4 s:", snapshot)
        # every pose becomes an /odom on each distro (a window's edges, and a machine loaded by two full-speed floods,
        # where the adapter answering two nodes' subscribers fell 14 % behind, leave the margin)
        for distro in ("humble", "jazzy"):
            assert snapshot[f"{distro} odom"] >= 0.8 * snapshot["pose"], snapshot
            assert snapshot[f"{distro} joint_states"] >= 0.75 * snapshot["pose"], snapshot
            assert snapshot[f"{distro} tf"] >= 1.6 * snapshot["pose"], snapshot  # odom -> base_footprint, and the wheels
        assert node.received("/odom", 20, "/odom at the Jazzy SDK")["count"] >= 20
        assert moved(session, lambda: node.ask(op="publish", topic="/cmd_vel", type="geometry_msgs/msg/Twist",
                                               message={"linear": {"x": 0.3}}, rate_hz=10, duration_s=1.5)) > 0.15  # fmt: skip
        assert_humble_drives_and_sees_odom(session)


def late_transient_local(session: zenoh.Session, key: str) -> list[tuple[str, bytes]]:
    """A transient-local subscription as rmw_zenoh's ``rmw_subscription_data.cpp`` declares one (every distro): an
    AdvancedSubscriber that detects late publishers and queries their caches for history (depth 1)."""
    got: list[tuple[str, bytes]] = []
    zenoh.ext.declare_advanced_subscriber(
        session,
        key,
        lambda s: got.append((str(s.key_expr), s.payload.to_bytes())),
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
        subscriber_detection=True,
    )
    return got


def test_a_fleet_of_three_has_each_robots_description_and_frames(children: list[Child], sdk: Any, tmp_path: Path) -> None:
    """/r2/robot_description and the absolute /tf_static as a late rmw_zenoh subscription gets them (zenoh-ros2-sdk 0.1.8
    cannot: its late-joiner query looks for the token of ``%r2/robot_description``, a namespaced name it does not mangle);
    /r2/odom through the SDK."""
    import zenoh.ext

    from blackmetal.ros2.messages import RosCodec

    port = ros_graph(children, "--robots", "3")
    node = sdk(port)
    node.ask(op="subscribe", topic="/r2/odom", type="nav_msgs/msg/Odometry")
    odom = node.received("/r2/odom", 5, "/r2/odom")["last"]
    assert (odom["header"]["frame_id"], odom["child_frame_id"]) == ("r2/odom", "r2/base_footprint")
    codec = RosCodec()
    with zenoh.open(client_config(port)) as session:
        descriptions = late_transient_local(session, f"0/r2/robot_description/std_msgs::msg::dds_::String_/{STRING_HASH}")
        statics = late_transient_local(session, "0/tf_static/tf2_msgs::msg::dds_::TFMessage_/*")
        wait_for(lambda: descriptions, what="/r2/robot_description from the publisher's cache")
        urdf = codec.decode(descriptions[0][1], "std_msgs/msg/String").data
        path = tmp_path / "r2.urdf"
        path.write_text(urdf)
        checked = subprocess.run([check_urdf(), str(path)], capture_output=True, text=True, timeout=60)
        assert checked.returncode == 0 and "root Link: r2/base_footprint" in checked.stdout, checked.stdout
        assert all((link.get("name") or "").startswith("r2/") for link in ET.fromstring(urdf).iter("link"))
        # /tf_static is absolute: each robot's node has its own cache on it, and the late subscriber gets all three
        wait_for(lambda: len(statics) >= 3, what="/tf_static from the three nodes' caches")
        pairs = set()
        for _, payload in statics:
            for t in codec.decode(payload, "tf2_msgs/msg/TFMessage").transforms:
                pairs.add((t.header.frame_id, t.child_frame_id))
        assert pairs == {
            (f"{r}/{a}", f"{r}/{b}") for r in ("r1", "r2", "r3") for a, b in (("base_footprint", "base_link"), ("base_link", "caster"))
        }


def test_jazzy_sdk_lists_and_sets_a_speed_limit_and_the_robots_wire_shows_it(children: list[Child], sdk: Any) -> None:
    """``ros2 param list`` / ``set`` as the SDK's service client does them: the gateway's table, a speed limit set
    through the gateway's own key (the robot's wire then carries commands clamped to it), an out-of-range value
    refused with the gateway's reason, each change on /parameter_events. A robot written for the tests (its wire log)
    and the gateway stand in for ``up``'s simulator, so what reached the robot is read byte for byte."""
    from rogue_robot import Behaviour, RogueRobot
    from unit.ros2.test_services import PARAMETER_EVENT_HASH, PARAMETER_SERVICE_HASHES

    velocity = int(CommandCode.SET_LR_WHEEL_VELOCITY)
    robot = RogueRobot(Behaviour()).start()
    try:
        port = free_port()
        router = Child(["-m", "blackmetal", "router", "-c", str(ROS2_DEPLOY / "rmw_zenohd.json5"), "-l", f"tcp/127.0.0.1:{port}"])
        children.append(router)
        router.ready()
        endpoint = ["-e", f"tcp/127.0.0.1:{port}", "--no-multicast-scouting"]
        gateway = Child(["-m", "blackmetal", "gateway", "--control-port", str(robot.control_port), "--log-port", str(robot.log_port),
                         "--cmd-timeout", "0", *endpoint])  # fmt: skip
        ros2 = Child(["-m", "blackmetal", "ros2", "--distro", "jazzy", *endpoint])
        children.extend([gateway, ros2])
        gateway.ready()
        ready = ros2.ready()
        for name, (_, type_hash) in PARAMETER_SERVICE_HASHES.items():
            assert ready["services"][name].endswith(type_hash) and ready["services"][name].startswith(f"0/blackmetal/{name}/")
        node = sdk(port)
        events_key = node.ask(op="subscribe", topic="/parameter_events", type="rcl_interfaces/msg/ParameterEvent")["key"]
        assert events_key == f"0/parameter_events/rcl_interfaces::msg::dds_::ParameterEvent_/{PARAMETER_EVENT_HASH}"

        listed = node.ask(op="call", service="/blackmetal/list_parameters", type="rcl_interfaces/srv/ListParameters",
                          request={"prefixes": [], "depth": 0})  # fmt: skip
        assert listed.get("ok"), listed
        assert listed["key"] == ready["services"]["list_parameters"]  # the SDK's own hash of the genuine .srv is ours
        names = listed["response"]["result"]["names"]
        assert {"max_wheel_speed", "cmd_timeout", "wheel_separation", "sources.teleop.priority"} <= set(names)
        assert "sources.teleop" in listed["response"]["result"]["prefixes"]

        with zenoh.open(client_config(port)) as session:
            session.put("robot/cmd_vel", json.dumps({"linear": {"x": 0.6}}))
            wait_for(lambda: any(c[1] == (0.6, 0.6) for c in robot.commands(velocity)), what="the robot driving at 0.6 m/s")

        def set_params(*values: tuple[str, dict[str, Any]]) -> dict[str, Any]:
            answer = node.ask(op="call", service="/blackmetal/set_parameters", type="rcl_interfaces/srv/SetParameters",
                              request={"parameters": [{"name": n, "value": v} for n, v in values]})  # fmt: skip
            assert answer.get("ok"), answer
            return answer

        set_params(("max_wheel_speed", {"type": 3, "double_value": 0.5}))  # the SDK's client is made (and waited for) once
        answer = set_params(("max_wheel_speed", {"type": 3, "double_value": 0.25}))
        assert answer["response"]["results"] == [{"successful": True, "reason": ""}]
        start = answer["started"]
        (arrival, _), *_ = wait_for(lambda: [c for c in robot.commands(velocity, since=start) if c[1] == (0.25, 0.25)],
                                    what="commands clamped to 0.25 m/s on the robot's wire")  # fmt: skip
        print(f"set_parameters max_wheel_speed 0.5 -> 0.25: the SDK's call {1000 * answer['elapsed_s']:.1f} ms; "
              f"on the robot's wire {1000 * (arrival - start):.1f} ms after the call began")  # fmt: skip
        assert all(c[1] is None or max(map(abs, c[1])) <= 0.25 for c in robot.commands(velocity, since=arrival))

        refused = set_params(("max_wheel_speed", {"type": 3, "double_value": 9.0}), ("wheel_radius", {"type": 3, "double_value": 0.2}))
        (speed, radius) = refused["response"]["results"]
        assert not speed["successful"] and "max_wheel_speed must be within" in speed["reason"]
        assert not radius["successful"] and "read-only" in radius["reason"]

        got = node.ask(op="call", service="/blackmetal/get_parameters", type="rcl_interfaces/srv/GetParameters",
                       request={"names": ["max_wheel_speed", "nonexistent"]})  # fmt: skip
        values = got["response"]["values"]
        assert (values[0]["type"], values[0]["double_value"]) == (3, 0.25) and values[1]["type"] == 0  # NOT_SET

        def changed_speed() -> bool:
            last = node.ask(op="received", topic="/parameter_events")["last"] or {}
            return any(p["name"] == "max_wheel_speed" and p["value"]["double_value"] == 0.25 for p in last.get("changed_parameters", []))

        wait_for(changed_speed, what="max_wheel_speed changed on /parameter_events")
        assert (node.ask(op="received", topic="/parameter_events")["last"] or {})["node"] == "/blackmetal"
    finally:
        robot.stop()
