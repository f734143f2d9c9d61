"""The ROS 2 adapter's services (set_estop, reset_odometry) and /diagnostics, with the test playing ROS 2's side.

No ROS 2 is installed here. The service client does on the wire exactly what
rmw_zenoh's ``ClientData::send_request`` does: it holds an ``SC`` liveliness
token, its GID is the XXH3-128 of that token, and each call is a ``get`` on
``<domain>/<service>/<type>/<RIHS01 hash>`` targeting complete queryables,
with the CDR request as payload and the 33-byte attachment (sequence number,
source timestamp, client GID); the reply must carry the same sequence number
and GID in its attachment and the CDR response (``take_response``). The
/diagnostics subscriber is an rmw_zenoh subscription: the DiagnosticArray key,
the publisher's attachment, and the CDR read with a reader written here from
the IDL layout (not rosbags). The type hashes below are ROS 2 Jazzy's own.
"""

from __future__ import annotations

import itertools
import math
import struct
import time
from typing import Any

import pytest
import zenoh
from helpers import TIMEOUT, Child, client_config, free_port, start_robot, wait_for, zenoh_connect_args

from blackmetal.robot_model import Encoders
from blackmetal.ros2.calls import ESTOP_REPEAT_S
from blackmetal.ros2.core import Ros2Core
from blackmetal.ros2.messages import RosCodec
from blackmetal.ros2.naming import PARAMETER_SERVICES, NodeIdentity, Qos, ServiceRole, attachment, gid_of, parse_attachment
from blackmetal.ros2.options import Ros2Options
from blackmetal.ros2.ros_types import BOOL, DIAGNOSTIC_ARRAY, SET_BOOL, TRIGGER, Frames
from blackmetal.ros2.settings import diagonal_matrix
from blackmetal.runtime.diagnostics import HEALTH_STALE_S, POSE_STALE_S, REJECTED_ERROR_COUNT, Level
from blackmetal.schemas import ErrorReport, EStop, GatewayHealth, Keys, LinkHealth, Pose, decode, encode, make_pose

# ROS 2 Jazzy's hashes (rosidl), not computed here: the adapter's must equal them.
SET_BOOL_HASH = "RIHS01_abe9e4bb6b41b40e6789712c00ec8871923e089af3f667a79992a428cff2da0a"
TRIGGER_HASH = "RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f"
DIAGNOSTIC_ARRAY_HASH = "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e"
#: The parameter services' types and hashes as ROS 2 generates them (rosidl's type descriptions; the same on Jazzy,
#: Kilted and Rolling, and what an rclcpp node's ``ros2 service list -t`` keys carry), written down, not computed here.
PARAMETER_SERVICE_HASHES = {
    "get_parameters": ("GetParameters", "RIHS01_bf9803d5c74cf989a5de3e0c2e99444599a627c7ff75f97b8c05b01003675cbc"),
    "get_parameter_types": ("GetParameterTypes", "RIHS01_da199c878688b3e530bdfe3ca8f74cb9fa0c303101e980a9e8f260e25e1c80ca"),
    "set_parameters": ("SetParameters", "RIHS01_56eed9a67e169f9cb6c1f987bc88f868c14a8fc9f743a263bc734c154015d7e0"),
    "set_parameters_atomically": ("SetParametersAtomically", "RIHS01_0e192ef259c07fc3c07a13191d27002222e65e00ccec653ca05e856f79285fcd"),
    "describe_parameters": ("DescribeParameters", "RIHS01_845b484d71eb0673dae682f2e3ba3c4851a65a3dcfb97bddd82c5b57e91e4cff"),
    "list_parameters": ("ListParameters", "RIHS01_3e6062bfbb27bfb8730d4cef2558221f51a11646d78e7bb30a1e83afac3aad9d"),
}
#: navigate_to_pose's services on Jazzy: CancelGoal's is ROS 2's own (written down); NavigateToPose's computed by the
#: construction test_action_types.py holds to the published Fibonacci hashes, written down here so that a change shows.
CANCEL_GOAL_HASH = "RIHS01_573d8b0a534451d7bc2ac8c5ffde8ac14b8593b7001175d0cd6516dcbeb8689a"
SEND_GOAL_HASH = "RIHS01_a4fcb3bee1bf32e21a0e541a943b221aa0826996e2c98f079b47022b256f48b5"
GET_RESULT_HASH = "RIHS01_c407920357d566771e8882b4ef4d1f1a84ee922d609920ccd57faa6d6e391dc5"
PARAMETER_EVENT_HASH = "RIHS01_043e627780fcad87a22d225bc2a037361dba713fca6a6b9f4b869a5aa0393204"
SET_ESTOP_KEY = f"0/set_estop/std_srvs::srv::dds_::SetBool_/{SET_BOOL_HASH}"
RESET_KEY = f"0/reset_odometry/std_srvs::srv::dds_::Trigger_/{TRIGGER_HASH}"
DIAGNOSTICS_KEY = f"0/diagnostics/diagnostic_msgs::msg::dds_::DiagnosticArray_/{DIAGNOSTIC_ARRAY_HASH}"
GID = bytes(range(16))


@pytest.fixture(scope="module")
def codec() -> RosCodec:
    return RosCodec()


# ------------------------------------------------------------------ CDR as the IDL lays it out, written independently of rosbags
def set_bool_request(value: bool) -> bytes:
    return b"\x00\x01\x00\x00" + bytes([value])


TRIGGER_REQUEST = b"\x00\x01\x00\x00\x00"  # the empty request's placeholder byte


def encode_request(codec: RosCodec, service: str, **fields: Any) -> bytes:
    """A ``<service>_Request`` as a ROS client sends it (Trigger: no fields; SetParameters: ``parameters`` as
    (name, value) pairs)."""
    if service == TRIGGER:
        fields = {"structure_needs_at_least_one_member": 0}
    if "parameters" in fields:
        fields["parameters"] = codec.parameters(fields["parameters"])
    return codec.encode(f"{service}_Request", **fields)


class Cdr:
    """Little-endian CDR reader: each primitive aligned to its size, counted after the 4-byte header."""

    def __init__(self, data: bytes) -> None:
        assert data[:4] == b"\x00\x01\x00\x00", data[:4].hex()
        self.body, self.pos = data[4:], 0

    def take(self, fmt: str) -> Any:
        size = struct.calcsize("<" + fmt)
        self.pos += -self.pos % size
        (value,) = struct.unpack_from("<" + fmt, self.body, self.pos)
        self.pos += size
        return value

    def string(self) -> str:
        length = self.take("I")  # includes the NUL
        text = self.body[self.pos : self.pos + length - 1].decode()
        assert self.body[self.pos + length - 1] == 0
        self.pos += length
        return text

    def done(self) -> bool:
        return self.pos == len(self.body)


def read_response(data: bytes) -> tuple[bool, str]:
    """SetBool_Response / Trigger_Response: bool success, string message."""
    r = Cdr(data)
    success, message = r.take("?"), r.string()
    assert r.done()
    return success, message


def read_diagnostics(data: bytes) -> dict[str, dict[str, Any]]:
    """DiagnosticArray -> {status name: {level, message, hardware_id, values}}."""
    r = Cdr(data)
    r.take("i"), r.take("I"), r.string()  # header: stamp, frame_id
    statuses = {}
    for _ in range(r.take("I")):
        level, name, message, hardware_id = r.take("B"), r.string(), r.string(), r.string()
        values = {r.string(): r.string() for _ in range(r.take("I"))}
        statuses[name] = {"level": level, "message": message, "hardware_id": hardware_id, "values": values}
    assert r.done(), "trailing bytes after the DiagnosticArray"
    return statuses


def test_hashes_keys_and_the_independent_reader_agree_with_the_codec(codec: RosCodec) -> None:
    assert codec.type_hash(SET_BOOL) == SET_BOOL_HASH and codec.type_hash(TRIGGER) == TRIGGER_HASH
    assert codec.type_hash(DIAGNOSTIC_ARRAY) == DIAGNOSTIC_ARRAY_HASH
    assert codec.request(SET_BOOL, set_bool_request(True)).data is True and codec.request(SET_BOOL, set_bool_request(False)).data is False
    codec.request(TRIGGER, TRIGGER_REQUEST)
    assert encode_request(codec, TRIGGER) == TRIGGER_REQUEST and encode_request(codec, SET_BOOL, data=True) == set_bool_request(True)
    assert read_response(codec.response(SET_BOOL, success=True, message="done")) == (True, "done")
    node = NodeIdentity(domain_id=0, zid="abc", name="blackmetal")
    token = node.entity_token(7, ServiceRole.SERVER, "/set_estop", SET_BOOL, SET_BOOL_HASH, Qos())
    assert token == f"@ros2_lv/0/abc/0/7/SS/%/%/blackmetal/%set_estop/std_srvs::srv::dds_::SetBool_/{SET_BOOL_HASH}/::,10:,:,:,,"


# ------------------------------------------------------------------ the core, no Zenoh, on a fake clock
class Recorder:
    def __init__(self) -> None:
        self.ros_out: list[tuple[str, bytes]] = []
        self.forwarded: list[tuple[str, bytes]] = []
        self.errors: list[ErrorReport] = []
        self.replies: dict[int, tuple[bytes, bytes | None]] = {}
        self.refused: dict[int, str] = {}
        self.queries: list[tuple[str, bytes | None, int, float]] = []
        self.followed: list[frozenset[str]] = []

    def ros(self, topic: str, cdr: bytes) -> None:
        self.ros_out.append((topic, cdr))

    def blackmetal(self, key: str, payload: bytes) -> None:
        self.forwarded.append((key, payload))

    def error(self, message: ErrorReport) -> None:
        self.errors.append(message)

    def service_reply(self, call: int, cdr: bytes, attachment: bytes | None) -> None:
        assert call not in self.replies and call not in self.refused, "answered twice"
        self.replies[call] = (cdr, attachment)

    def service_refuse(self, call: int, reason: str) -> None:
        assert call not in self.replies and call not in self.refused, "answered twice"
        self.refused[call] = reason

    def query(self, key: str, payload: bytes | None, tag: int, timeout: float) -> None:
        self.queries.append((key, payload, tag, timeout))

    def follow(self, streams: frozenset[str]) -> None:
        self.followed.append(streams)

    def answer(self, call: int) -> tuple[bool, str]:
        return read_response(self.replies[call][0])

    def diagnostics(self) -> dict[str, dict[str, Any]]:
        return read_diagnostics([cdr for topic, cdr in self.ros_out if topic == "diagnostics"][-1])


def make_core(codec: RosCodec) -> tuple[Ros2Core, Recorder]:
    out = Recorder()
    options = Ros2Options(
        frames=Frames(),
        pose_covariance=diagonal_matrix("0,0,0,0,0,0", "p"),
        twist_covariance=diagonal_matrix("0,0,0,0,0,0", "t"),
        publish_tf=False,
        joint_names=("l", "r"),
        wheel_radius=0.1,
        encoders=Encoders(),
        service_timeout=2.0,
        expected_poll_hz=50.0,
        service_keys={"set_estop": SET_ESTOP_KEY, "reset_odometry": RESET_KEY},
    )
    return Ros2Core(options, Keys(), out, codec, wallclock=lambda: 1_700_000_000.0), out


def health(estop: bool = False, poll_hz: float = 50.0, control: str = "connected", rtt: float | None = 2.0, **extra: Any) -> bytes:
    return encode(
        GatewayHealth(
            stamp=1_700_000_000.0,
            control=LinkHealth(state=control),
            log=LinkHealth(state="connected"),
            estop=estop,
            poll_hz=poll_hz,
            last_rtt_ms=rtt,
            source="run1",
            active_source="ros2",
            **extra,
        )
    )


def test_set_estop_is_answered_once_the_health_confirms_it(codec: RosCodec) -> None:
    core, out = make_core(codec)
    core.calls.on_service_request("set_estop", 1, set_bool_request(True), attachment(41, 123, GID), now=10.0)
    assert out.forwarded == [("robot/estop", encode(EStop(engaged=True)))]
    assert [q[0] for q in out.queries] == ["robot/gateway/health"]
    core.on_health(health(estop=False), now=10.05)  # not yet
    assert out.replies == {}
    core.tick(10.0 + ESTOP_REPEAT_S)  # put again, ask again, as `blackmetal estop` does
    assert len(out.forwarded) == 2 and len(out.queries) == 2
    core.on_query_reply(out.queries[-1][2], True, health(estop=True), now=10.15)
    success, message = out.answer(1)
    assert success and "e-stop engaged" in message and "confirmed" in message
    sequence, stamp, gid = parse_attachment(out.replies[1][1] or b"")
    assert (sequence, gid) == (41, GID) and stamp == 1_700_000_000 * 10**9  # the request's id, the server's time
    core.tick(20.0)  # nothing pending any more: no more puts
    assert len(out.forwarded) == 2 and core.calls.pending == {}


def test_set_estop_false_and_estop_false_release_on_the_release_key(codec: RosCodec) -> None:
    """A release goes on estop/release, the key a secure router gives to the safety role (a release on estop is refused)."""
    core, out = make_core(codec)
    core.calls.on_service_request("set_estop", 1, set_bool_request(False), attachment(1, 1, GID), now=10.0)
    assert out.forwarded == [("robot/estop/release", encode(EStop(engaged=False)))]
    core.on_estop(codec.encode(BOOL, data=False), now=10.1)
    core.on_estop(codec.encode(BOOL, data=True), now=10.2)
    assert out.forwarded[1:] == [("robot/estop/release", encode(EStop(engaged=False))), ("robot/estop", encode(EStop(engaged=True)))]


def test_set_estop_unconfirmed_is_false_at_the_deadline_with_the_reason(codec: RosCodec) -> None:
    core, out = make_core(codec)
    core.calls.on_service_request("set_estop", 1, set_bool_request(True), attachment(1, 1, GID), now=10.0)
    core.on_health(health(estop=False), now=10.05)
    for step in range(1, 20):  # 10.1 .. 11.9: put again every 100 ms, never confirmed
        core.tick(10.0 + 0.1 * step)
    assert 1 not in out.replies and len(out.forwarded) == 20
    core.tick(12.0)
    success, message = out.answer(1)
    assert not success and "did not confirm the e-stop on within 2 s" in message and "estop=false" in message
    assert len(out.forwarded) == 20  # given up: no more puts

    core.calls.on_service_request("set_estop", 2, set_bool_request(True), attachment(2, 1, GID), now=20.0)
    core.calls.on_service_request("set_estop", 3, set_bool_request(False), None, now=20.0)  # no attachment: answered without one
    assert out.answer(2) == (False, "superseded: set_estop off was called since")  # never puts "on" over the "off"
    core.on_health(health(estop=False), now=20.1)
    assert out.answer(3)[0] is True and out.replies[3][1] is None

    core2, out2 = make_core(codec)  # no gateway at all
    core2.calls.on_service_request("set_estop", 5, set_bool_request(True), attachment(5, 1, GID), now=0.0)
    core2.tick(2.0)
    success, message = out2.answer(5)
    assert not success and "no health on robot/gateway/health" in message and "is the gateway running" in message


def test_reset_odometry_is_answered_by_the_odometrys_reply(codec: RosCodec) -> None:
    core, out = make_core(codec)
    core.calls.on_service_request("reset_odometry", 1, TRIGGER_REQUEST, attachment(3, 1, GID), now=0.0)
    key, payload, tag, timeout = out.queries[-1]
    assert key == "robot/odometry/reset" and payload is None and timeout == 2.0
    core.on_query_reply(tag, True, encode(make_pose(1.0, 0.0, 0.0, 0.0)), now=0.1)
    core.calls.on_query_done(tag, now=0.1)
    assert out.answer(1) == (True, "odometry reset to x=0 y=0 yaw=0 (confirmed by the odometry on robot/odometry/reset)")

    core.calls.on_service_request("reset_odometry", 2, TRIGGER_REQUEST, None, now=1.0)
    core.calls.on_query_done(out.queries[-1][2], now=1.0)  # nobody answered
    success, message = out.answer(2)
    assert not success and "no odometry answered" in message

    core.calls.on_service_request("reset_odometry", 3, TRIGGER_REQUEST, None, now=2.0)
    core.on_query_reply(out.queries[-1][2], False, b"PoseReset: reset refused", now=2.0)
    assert out.answer(3) == (False, "the odometry refused the reset: PoseReset: reset refused")

    core.calls.on_service_request("reset_odometry", 4, TRIGGER_REQUEST, None, now=3.0)
    core.tick(5.0)  # the query never finished: the deadline answers
    assert out.answer(4)[0] is False and "did not answer the reset within 2 s" in out.answer(4)[1]


def test_bad_requests_are_reported_and_answered(codec: RosCodec) -> None:
    core, out = make_core(codec)
    core.calls.on_service_request("set_estop", 1, b"\x00\x01\x00\x00", attachment(1, 1, GID), now=0.0)  # no data byte
    success, message = out.answer(1)
    assert not success and "invalid request" in message and parse_attachment(out.replies[1][1] or b"")[0] == 1
    core.calls.on_service_request("set_estop", 2, set_bool_request(True), b"\x01\x02", now=0.0)  # not rmw_zenoh's attachment
    assert "not rmw_zenoh's" in out.refused[2]
    assert [e.key for e in out.errors] == [SET_ESTOP_KEY, SET_ESTOP_KEY] and all(e.source == "ros2" for e in out.errors)
    assert ("robot/estop", encode(EStop(engaged=True))) not in out.forwarded  # nothing was put for a bad request


def test_diagnostics_levels_follow_the_thresholds(codec: RosCodec) -> None:
    core, out = make_core(codec)
    core.tick(0.0)
    assert core.next_deadline() == 1.0  # 1 Hz
    statuses = out.diagnostics()
    assert list(statuses) == ["blackmetal: robot link", "blackmetal: odometry", "blackmetal: ROS 2 adapter"]
    assert [s["level"] for s in statuses.values()] == [Level.STALE, Level.STALE, Level.OK]
    assert all(s["hardware_id"] == "robot" for s in statuses.values())

    def at(now: float) -> dict[str, dict[str, Any]]:  # the statuses at ``now``, as /diagnostics would carry them
        return {d.name: {"level": d.level, "message": d.message, "values": dict(d.values)} for d in core.statuses(now)}

    core.on_alive("gateway", True, now=0.5)
    core.on_alive("odometry", True, now=0.5)
    core.on_health(health(lost_replies=0, polls=100), now=0.5)
    core.on_pose(encode(make_pose(1.0, 0.0, 0.0, 0.0)), now=0.9)
    core.tick(1.0)  # due: published, and read back from the CDR
    link, odometry = out.diagnostics()["blackmetal: robot link"], out.diagnostics()["blackmetal: odometry"]
    assert (link["level"], link["message"]) == (Level.OK, "connected, polling at 50 Hz")
    assert link["values"]["control link"] == "connected" and link["values"]["e-stop"] == "released"
    assert link["values"]["active source"] == "ros2" and link["values"]["round trip (ms)"] == "2.0"
    assert odometry["level"] == Level.OK and odometry["values"]["pose age (s)"] == "0.10"

    core.on_health(health(estop=True, poll_hz=40.0, lost_replies=1, polls=300), now=1.5)  # 1 of 200 lost, 80 %, stopped
    link = at(2.0)["blackmetal: robot link"]
    # an engaged e-stop is ERROR (the shared severity table, as in the Foxglove view): the worst reason, first
    assert link["level"] == Level.ERROR and link["message"].startswith("e-stop engaged") and "1 of 200 replies lost" in link["message"]
    assert "polling at 40 Hz of 50 Hz" in link["message"]
    core.on_health(health(poll_hz=20.0, rtt=300.0), now=2.5)
    link = at(3.0)["blackmetal: robot link"]
    assert link["level"] == Level.ERROR and "round trip 300 ms" in link["message"]
    core.on_health(health(control="down"), now=3.5)
    assert at(4.0)["blackmetal: robot link"]["message"].startswith("control link down")
    link = at(3.5 + HEALTH_STALE_S + 0.5)["blackmetal: robot link"]
    assert link["level"] == Level.STALE and "no gateway health for" in link["message"]
    core.on_alive("gateway", False, now=8.0)
    link = at(8.0)["blackmetal: robot link"]
    assert link["level"] == Level.ERROR and "the gateway is not running" in link["message"]

    odometry = at(0.9 + POSE_STALE_S + 0.1)["blackmetal: odometry"]
    assert odometry["level"] == Level.STALE and "no pose for 2.1 s" in odometry["message"]
    core.on_pose(encode(make_pose(9.0, 0.0, 0.0, 0.0)), now=9.0)
    rejected = ErrorReport(stamp=1.0, source="odometry", key="robot/wheels/impulses", reason="out of order")
    core.on_error_report(encode(rejected), now=9.0)
    core.on_error_report(encode(ErrorReport(stamp=1.0, source="gateway", key="robot/wheels/impulses", reason="x")), now=9.0)
    odometry = at(9.0)["blackmetal: odometry"]
    assert odometry["level"] == Level.WARN and odometry["values"]["rejected samples (10 s)"] == "1"
    assert odometry["values"]["last rejection"] == "out of order"
    summary = ErrorReport(stamp=1.0, source="odometry", key="robot/wheels/impulses", reason="rate-limited", suppressed=REJECTED_ERROR_COUNT)
    core.on_error_report(encode(summary), now=9.1)
    assert at(9.1)["blackmetal: odometry"]["level"] == Level.ERROR
    core.on_alive("odometry", False, now=9.2)
    odometry = at(9.2)["blackmetal: odometry"]
    assert odometry["level"] == Level.ERROR and "the odometry is not running" in odometry["message"]

    core.on_cmd_vel(b"", now=9.3)  # a bad ROS input: the adapter warns for 10 s
    adapter = at(9.3)["blackmetal: ROS 2 adapter"]
    assert adapter["level"] == Level.WARN and adapter["values"]["bad ROS inputs (10 s)"] == "1"
    assert at(19.4)["blackmetal: ROS 2 adapter"]["level"] == Level.OK


# ------------------------------------------------------------------ on Zenoh: rmw_zenoh's service client and subscriber
class RmwZenohClient:
    """Calls services exactly as rmw_zenoh's ClientData does: SC token, GID from it, get with the attachment."""

    def __init__(self, session: zenoh.Session, service: str, ros_type: str, type_hash: str, entity_id: int) -> None:
        node = NodeIdentity(domain_id=0, zid=str(session.zid()), name="test_client")
        self.token = node.entity_token(entity_id, ServiceRole.CLIENT, f"/{service}", ros_type, type_hash, Qos())
        self.liveliness = session.liveliness().declare_token(self.token)
        self.gid = gid_of(self.token)
        self.session = session
        self.key = f"0/{service}/{ros_type.replace('/srv/', '::srv::dds_::')}_/{type_hash}"
        self.sequence = 0

    def call(self, request: bytes, timeout: float = TIMEOUT) -> tuple[bool, str, float]:
        """(success, message, seconds until the reply); fails the test on anything rmw_zenoh would refuse."""
        self.sequence += 1
        start = time.monotonic()
        replies = list(
            self.session.get(
                self.key,
                payload=request,
                attachment=attachment(self.sequence, time.time_ns(), self.gid),
                target=zenoh.QueryTarget.ALL_COMPLETE,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=timeout,
            )
        )
        elapsed = time.monotonic() - start
        assert len(replies) == 1 and replies[0].ok is not None, [r.err.payload.to_string() for r in replies if r.err is not None]
        sample = replies[0].ok
        assert str(sample.key_expr) == self.key
        assert sample.attachment is not None, "rmw_zenoh's take_response needs the attachment"
        sequence, stamp, gid = parse_attachment(sample.attachment.to_bytes())
        assert (sequence, gid) == (self.sequence, self.gid) and abs(stamp - time.time_ns()) < 60 * 10**9
        success, message = read_response(sample.payload.to_bytes())
        return success, message, elapsed


def gateway_health(session: zenoh.Session) -> GatewayHealth | None:
    replies = [r for r in session.get("robot/gateway/health", timeout=2) if r.ok is not None]
    return decode(GatewayHealth, replies[0].ok.payload.to_bytes()) if replies else None


def pose(session: zenoh.Session) -> Pose:
    replies = [r for r in session.get("robot/pose", timeout=5) if r.ok is not None]
    assert replies, "no answer from the odometry"
    return decode(Pose, replies[0].ok.payload.to_bytes())


@pytest.mark.integration
def test_services_and_diagnostics_as_rmw_zenoh_sees_them(children: list[Child], codec: RosCodec) -> None:
    zport = free_port()
    _, gateway, odometry = start_robot(children, zport, gateway_args=("--poll-hz", "50"))
    ros2 = Child(["-m", "blackmetal.ros2", *zenoh_connect_args(zport)])
    bridge = Child(["-m", "blackmetal", "ros2", "--flavor", "bridge", "--namespace", "r1", *zenoh_connect_args(zport)])
    children.extend([ros2, bridge])
    ready = ros2.ready()
    assert {k: ready["services"][k] for k in ("set_estop", "reset_odometry")} == {"set_estop": SET_ESTOP_KEY, "reset_odometry": RESET_KEY}
    assert ready["keys"]["diagnostics"] == DIAGNOSTICS_KEY
    assert bridge.ready()["services"] == {"set_estop": "r1/set_estop", "reset_odometry": "r1/reset_odometry"} | {
        name: f"r1/blackmetal/{name}" for name in PARAMETER_SERVICES
    } | {f"navigate_to_pose/_action/{name}": f"r1/navigate_to_pose/_action/{name}" for name in ("send_goal", "cancel_goal", "get_result")}
    with zenoh.open(client_config(zport)) as session:
        arrays: list[tuple[float, dict[str, dict[str, Any]]]] = []

        def on_diagnostics(sample: zenoh.Sample) -> None:
            assert sample.attachment is not None and len(sample.attachment.to_bytes()) == 33
            arrays.append((time.monotonic(), read_diagnostics(sample.payload.to_bytes())))

        session.declare_subscriber(DIAGNOSTICS_KEY, on_diagnostics)

        def latest(name: str) -> dict[str, Any]:
            wait_for(lambda: arrays, what="/diagnostics")
            return arrays[-1][1][name]

        # the servers, as `ros2 service list` finds them
        def service_servers() -> dict[str, list[str]]:
            tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**", timeout=5) if r.ok is not None]
            return {t.split("/")[9]: t.split("/")[10:12] for t in tokens if t.split("/")[5] == "SS"}

        # a liveliness query on a loaded machine may come back before every token has answered: ask until both have
        servers = wait_for(lambda: len(found := service_servers()) >= 8 and found, what="the service servers' tokens")
        assert servers == {
            "%set_estop": ["std_srvs::srv::dds_::SetBool_", SET_BOOL_HASH],
            "%reset_odometry": ["std_srvs::srv::dds_::Trigger_", TRIGGER_HASH],
        } | {
            f"%blackmetal%{name}": [f"rcl_interfaces::srv::dds_::{type_name}_", type_hash]
            for name, (type_name, type_hash) in PARAMETER_SERVICE_HASHES.items()
        } | {
            "%navigate_to_pose%_action%send_goal": ["nav2_msgs::action::dds_::NavigateToPose_SendGoal_", SEND_GOAL_HASH],
            "%navigate_to_pose%_action%cancel_goal": ["action_msgs::srv::dds_::CancelGoal_", CANCEL_GOAL_HASH],
            "%navigate_to_pose%_action%get_result": ["nav2_msgs::action::dds_::NavigateToPose_GetResult_", GET_RESULT_HASH],
        }

        # /diagnostics at 1 Hz: all three OK once the robot runs
        wait_for(lambda: arrays and all(s["level"] == Level.OK for s in arrays[-1][1].values()), what="three OK statuses")
        link, odom, adapter = (latest(f"blackmetal: {n}") for n in ("robot link", "odometry", "ROS 2 adapter"))
        assert link["values"]["control link"] == "connected" and link["values"]["log link"] == "connected"
        assert 45 <= float(link["values"]["poll rate (Hz)"]) <= 55 and link["values"]["asked poll rate (Hz)"] == "50"
        assert link["values"]["e-stop"] == "released" and link["values"]["gateway alive"] == "yes"
        assert float(odom["values"]["pose age (s)"]) < 0.5 and odom["values"]["odometry alive"] == "yes"
        assert adapter["values"]["cmd_vel to"] == "robot/cmd_vel/ros2" and adapter["values"]["flavor"] == "rmw_zenoh"
        stamps = [t for t, _ in arrays[-3:]] if len(arrays) >= 3 else None
        if stamps:
            assert all(0.5 < b - a < 1.6 for a, b in itertools.pairwise(stamps)), stamps

        # set_estop true, then false: answered once the gateway's health shows it
        set_estop = RmwZenohClient(session, "set_estop", SET_BOOL, SET_BOOL_HASH, entity_id=1)
        success, message, _ = set_estop.call(set_bool_request(True))
        assert success and "e-stop engaged" in message, message
        assert (h := gateway_health(session)) is not None and h.estop is True
        wait_for(lambda: latest("blackmetal: robot link")["values"]["e-stop"] == "engaged", what="the e-stop in /diagnostics")
        assert latest("blackmetal: robot link")["level"] == Level.ERROR  # an engaged e-stop, as in the Foxglove view
        success, message, _ = set_estop.call(set_bool_request(False))
        assert success and "e-stop released" in message, message
        assert (h := gateway_health(session)) is not None and h.estop is False

        # reset_odometry: drive a little, stop, reset: the pose goes back to 0
        twist = codec.encode_twist(0.3, 0.3)
        cmd_vel = ready["keys"]["cmd_vel"]
        for _ in range(10):
            session.put(cmd_vel, twist)
            time.sleep(0.1)
        wait_for(lambda: math.hypot(pose(session).x, pose(session).y) > 0.05, what="a move")
        last: list[Pose] = [pose(session)]

        def stopped() -> bool:
            time.sleep(0.3)
            now = pose(session)
            still = math.hypot(now.x - last[0].x, now.y - last[0].y) < 1e-6
            last[0] = now
            return still

        wait_for(stopped, what="the robot at rest")
        reset = RmwZenohClient(session, "reset_odometry", TRIGGER, TRIGGER_HASH, entity_id=2)
        success, message, _ = reset.call(TRIGGER_REQUEST)
        assert success and "odometry reset" in message, message
        after = pose(session)
        assert abs(after.x) < 1e-3 and abs(after.y) < 1e-3 and abs(after.yaw) < 1e-3

        # the bridge flavour: a queryable on r1/set_estop, raw CDR both ways, no attachment
        replies = list(session.get("r1/set_estop", payload=set_bool_request(True), timeout=TIMEOUT))
        assert len(replies) == 1 and replies[0].ok is not None and replies[0].ok.attachment is None
        assert read_response(replies[0].ok.payload.to_bytes())[0] is True
        assert set_estop.call(set_bool_request(False))[0] is True

        # the gateway stops: the robot link turns ERROR (its token went) or STALE, and set_estop fails in time
        gateway.stop()
        # (the e-stop engaged just before is ERROR too: the status that says so may still be the latest for a second)
        link = wait_for(
            lambda: (s := latest("blackmetal: robot link"))["level"] in (Level.ERROR, Level.STALE) and "gateway" in s["message"] and s,
            what="robot link ERROR or STALE, saying why about the gateway",
        )
        assert link["level"] in (Level.ERROR, Level.STALE) and "gateway" in link["message"]
        success, message, elapsed = set_estop.call(set_bool_request(True))
        assert not success and "did not confirm the e-stop on within 2 s" in message and "no health" in message, message
        assert 1.5 < elapsed < 5.0, elapsed  # the service timeout, never a hang
        wait_for(lambda: latest("blackmetal: odometry")["level"] == Level.STALE, what="the odometry STALE without impulses")
        wait_for(lambda: latest("blackmetal: ROS 2 adapter")["level"] == Level.WARN, what="the failed call in the adapter's status")

        # the odometry stops too: reset_odometry fails at once, with the reason
        odometry.stop()
        wait_for(lambda: latest("blackmetal: odometry")["level"] == Level.ERROR, what="odometry ERROR once its token went")
        success, message, elapsed = reset.call(TRIGGER_REQUEST)
        assert not success and "no odometry answered" in message and elapsed < 5.0, message
        assert ros2.proc.poll() is None and bridge.proc.poll() is None
