"""A ROS 2 action client as rcl_action makes one over rmw_zenoh, on Humble and on Jazzy keys: the independent client of tests/integration/test_ros2_navigate.py.

Kilted and Rolling are spoken as Jazzy (the same key, token and attachment formats), each with its own
NavigateToPose (Rolling's feedback has two more fields, so another hash).

Written from the sources, never from our adapter:

* **rosidl**: tests/ros2_idl.py (the definitions' structures, their RIHS01 hashes, their CDR);
* **rcl_action** (https://github.com/ros2/rcl, ``rcl_action/src/rcl_action/names.c``, ``default_qos.h``):
  the action's three services and two topics, ``<action>/_action/{send_goal,cancel_goal,get_result}``,
  ``<action>/_action/{feedback,status}``, status transient local with depth 1; a client is ready when
  the three servers and the two publishers are in the graph (``rcl_action_server_is_available``);
* **rmw_zenoh** (https://github.com/ros2/rmw_zenoh, Humble 0.1.x and Jazzy 0.2.x): keys
  ``<domain>/<name without its outer slashes>/<pkg>::<kind>::dds_::<Type>_/<hash>`` (a service's type
  without ``Request_``), ``TypeHashNotSupported`` on Humble; liveliness tokens
  ``@ros2_lv/<domain>/<zid>/<nid>/<id>/<NN|MP|MS|SS|SC>/<enclave>/<ns>/<node>/<name>/<type>/<hash>/<qos>``
  with ``/`` written ``%``, an entity's GID the XXH3-128 of its token (``liveliness_utils.cpp``); a
  request is a get on the service key, target ALL_COMPLETE, no consolidation, get_result without a
  timeout (``rmw_client_data.cpp``), its payload CDR with the 4-byte encapsulation header and an
  attachment of int64 sequence number (from 1), int64 timestamp (ns) and the 16-byte GID after its
  length byte (``attachment_helpers.cpp``: 33 bytes); a reply carries the request's sequence number and
  the client's GID back; a transient-local subscription is an advanced subscriber that queries late
  publishers' caches (``rmw_subscription_data.cpp``).
"""

from __future__ import annotations

import math
import struct
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import xxhash
import zenoh
from ros2_idl import DISTROS, EMPTY_MEMBER, INTERFACES, LATER_DISTROS, FieldType, Interfaces, dds_type

__all__ = ["DISTROS", "EMPTY_MEMBER", "INTERFACES", "LATER_DISTROS", "FieldType", "Interfaces", "dds_type"]  # re-exported for the tests


def quaternion_from_yaw(yaw: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}


def yaw_of(q: dict[str, float]) -> float:
    return math.atan2(2 * (q["w"] * q["z"] + q["x"] * q["y"]), 1 - 2 * (q["y"] ** 2 + q["z"] ** 2))


# ------------------------------------------------------------------ the action client
#: GoalStatus and CancelGoal's return codes (action_msgs).
STATUS = {0: "UNKNOWN", 1: "ACCEPTED", 2: "EXECUTING", 3: "CANCELING", 4: "SUCCEEDED", 5: "CANCELED", 6: "ABORTED"}
CANCEL_CODES = {0: "ERROR_NONE", 1: "ERROR_REJECTED", 2: "ERROR_UNKNOWN_GOAL_ID", 3: "ERROR_GOAL_TERMINATED"}
SERVICE_QOS = "::,10:,:,:,,"  # rmw_qos_profile_services_default against rmw_zenoh's defaults
FEEDBACK_QOS = "::,10:,:,:,,"  # rmw_qos_profile_default
STATUS_QOS = ":1:,1:,:,:,,"  # rcl_action_qos_profile_status_default: transient local, depth 1


@dataclass
class Reply:
    """One service reply: its message, its attachment's fields, and how long the call took."""

    message: dict[str, Any]
    sequence: int
    timestamp_ns: int
    gid: bytes
    elapsed: float
    started: float


def attachment(sequence: int, gid: bytes, timestamp_ns: int | None = None) -> bytes:
    """rmw_zenoh's 33-byte attachment: int64 sequence, int64 ns timestamp, the GID's length byte and the GID."""
    return struct.pack("<qqB", sequence, time.time_ns() if timestamp_ns is None else timestamp_ns, 16) + gid


def read_attachment(raw: bytes) -> tuple[int, int, bytes]:
    if len(raw) != 33 or raw[16] != 16:
        raise ValueError(f"an attachment of {len(raw)} bytes, not rmw_zenoh's 33 (int64, int64, 16 + a 16-byte GID)")
    sequence, stamp = struct.unpack_from("<qq", raw)
    return sequence, stamp, raw[17:]


class ActionClient:
    """``rclcpp_action::Client<NavigateToPose>`` on one distro's rmw_zenoh keys, as a plain Zenoh session."""

    def __init__(
        self,
        session: zenoh.Session,
        distro: str,
        action: str = "/navigate_to_pose",
        action_type: str = "nav2_msgs/action/NavigateToPose",
        *,
        node: str = "navigate_client",
        domain: int = 0,
    ) -> None:
        assert distro in DISTROS + LATER_DISTROS, distro
        self.session, self.distro, self.action, self.action_type, self.domain = session, distro, action.rstrip("/"), action_type, domain
        self.interfaces = Interfaces(distro)
        self.zid = str(session.zid())
        self.node = node
        self._next_id = 1
        self._sequence = 0
        self._lock = threading.Lock()
        self.tokens_declared = [f"@ros2_lv/{domain}/{self.zid}/0/0/NN/%/%/{node}"]  # the key expressions, as declared
        self.tokens = [session.liveliness().declare_token(self.tokens_declared[0])]
        services = {
            "send_goal": f"{action_type}_SendGoal",
            "cancel_goal": "action_msgs/srv/CancelGoal",
            "get_result": f"{action_type}_GetResult",
        }
        topics = {"feedback": f"{action_type}_FeedbackMessage", "status": "action_msgs/msg/GoalStatusArray"}
        self.types = {**services, **topics}
        for typename in self.types.values():  # every structure parsed now, before Zenoh's threads read samples with them
            self.interfaces.fields(typename)
            for suffix in ("_Request", "_Response") if typename in services.values() else ():
                self.interfaces.type_description(typename + suffix)
            if typename not in services.values():
                self.interfaces.type_description(typename)
        self.keys = {part: self.key(f"{self.action}/_action/{part}", typename) for part, typename in self.types.items()}
        self.gids = {
            part: self._entity("SC", f"{self.action}/_action/{part}", typename, SERVICE_QOS) for part, typename in services.items()
        }
        self._entity("MS", f"{self.action}/_action/feedback", topics["feedback"], FEEDBACK_QOS)
        self._entity("MS", f"{self.action}/_action/status", topics["status"], STATUS_QOS)
        self.feedback: list[tuple[float, dict[str, Any], bytes | None]] = []  # (monotonic, FeedbackMessage, attachment)
        self.statuses: list[tuple[float, dict[str, Any]]] = []  # (monotonic, GoalStatusArray)
        self.errors: list[str] = []
        self._feedback_sub = session.declare_subscriber(self.keys["feedback"], self._on_feedback)
        import zenoh.ext

        self._status_sub = zenoh.ext.declare_advanced_subscriber(
            session,
            self.keys["status"],
            self._on_status,
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
            subscriber_detection=True,
        )

    # -------------------------------------------------------------- names
    def type_hash(self, typename: str) -> str:
        return self.interfaces.type_hash(typename)

    def key(self, name: str, typename: str) -> str:
        return f"{self.domain}/{name.strip('/')}/{dds_type(typename)}/{self.type_hash(typename)}"

    def _entity(self, kind: str, name: str, typename: str, qos: str) -> bytes:
        token = (
            f"@ros2_lv/{self.domain}/{self.zid}/0/{self._next_id}/{kind}/%/%/{self.node}/{name.replace('/', '%')}/"
            f"{dds_type(typename)}/{self.type_hash(typename)}/{qos}"
        )
        self._next_id += 1
        self.tokens_declared.append(token)
        self.tokens.append(self.session.liveliness().declare_token(token))
        return bytes(xxhash.xxh3_128_intdigest(token.encode()).to_bytes(16, "little"))

    # -------------------------------------------------------------- the graph
    def server_tokens(self) -> list[str]:
        return [str(r.ok.key_expr) for r in self.session.liveliness().get(f"@ros2_lv/{self.domain}/**", timeout=5) if r.ok is not None]

    def server_is_available(self) -> bool:
        """``rcl_action_server_is_available``: a server for each of the three services and a publisher on both topics,
        each with this distro's type name and hash."""
        found = set()
        for token in self.server_tokens():
            parts = token.split("/")
            if len(parts) < 13 or parts[3] == self.zid:
                continue
            kind, name, type_name, type_hash = parts[5], parts[9].replace("%", "/"), parts[10], parts[11]
            for part, typename in self.types.items():
                wanted = "SS" if part in self.gids else "MP"
                if (kind, name, type_name, type_hash) == (
                    wanted,
                    f"{self.action}/_action/{part}",
                    dds_type(typename),
                    self.type_hash(typename),
                ):
                    found.add(part)
        return found == set(self.types)

    # -------------------------------------------------------------- subscriptions
    def _on_feedback(self, sample: zenoh.Sample) -> None:
        raw = sample.attachment.to_bytes() if sample.attachment is not None else None
        try:
            message = self.interfaces.deserialize(self.types["feedback"], sample.payload.to_bytes())
        except Exception as exc:
            self.errors.append(f"feedback: {type(exc).__name__}: {exc}")
            return
        self.feedback.append((time.monotonic(), message, raw))

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            message = self.interfaces.deserialize(self.types["status"], sample.payload.to_bytes())
        except Exception as exc:
            self.errors.append(f"status: {type(exc).__name__}: {exc}")
            return
        self.statuses.append((time.monotonic(), message))

    # -------------------------------------------------------------- services
    def call(self, part: str, request: dict[str, Any], timeout: float = 10.0) -> Reply:
        """One request on ``part``'s service; its one reply (an AssertionError says why there is none)."""
        typename = self.types[part]
        with self._lock:
            self._sequence += 1
            sequence = self._sequence
        payload = self.interfaces.serialize(f"{typename}_Request", request)
        started = time.monotonic()
        replies = list(
            self.session.get(
                self.keys[part],
                payload=payload,
                attachment=attachment(sequence, self.gids[part]),
                target=zenoh.QueryTarget.ALL_COMPLETE,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=timeout,
            )
        )
        elapsed = time.monotonic() - started
        oks = [r.ok for r in replies if r.ok is not None]
        errs = [r.err.payload.to_bytes() for r in replies if r.err is not None]
        if len(oks) > 1:  # more than one server on this key: say what each answered
            answers = [self.interfaces.deserialize(f"{typename}_Response", ok.payload.to_bytes()) for ok in oks]
            raise AssertionError(f"{part}: {len(oks)} servers answered on {self.keys[part]}, one request: {answers}")
        assert len(oks) == 1, f"{part}: no reply in {elapsed:.2f} s (errors: {errs})"
        (reply,) = oks
        assert reply.attachment is not None, f"{part}: a reply without rmw_zenoh's attachment"
        echoed, stamp, gid = read_attachment(reply.attachment.to_bytes())
        message = self.interfaces.deserialize(f"{typename}_Response", reply.payload.to_bytes())
        return Reply(message, echoed, stamp, gid, elapsed, started)

    def send_goal(
        self,
        x: float,
        y: float,
        yaw: float,
        frame: str = "map",
        goal_id: bytes | None = None,
        behavior_tree: str = "",
        orientation: dict[str, float] | None = None,
    ) -> tuple[bytes, Reply]:
        """``async_send_goal``: a random UUID (rclcpp_action's generate_goal_id) and the goal pose stamped now."""
        import os

        goal_id = goal_id if goal_id is not None else os.urandom(16)
        now = time.time()
        request = {
            "goal_id": {"uuid": list(goal_id)},
            "goal": {
                "pose": {
                    "header": {"stamp": {"sec": int(now), "nanosec": int((now % 1) * 1e9)}, "frame_id": frame},
                    "pose": {"position": {"x": x, "y": y, "z": 0.0}, "orientation": orientation or quaternion_from_yaw(yaw)},
                },
                "behavior_tree": behavior_tree,
            },
        }
        return goal_id, self.call("send_goal", request)

    def get_result(self, goal_id: bytes, timeout: float = 120.0) -> Reply:
        """``async_get_result``: rmw_zenoh waits without a timeout for get_result; here ``timeout`` bounds a test."""
        return self.call("get_result", {"goal_id": {"uuid": list(goal_id)}}, timeout=timeout)

    def get_result_async(self, goal_id: bytes, timeout: float = 120.0) -> dict[str, Any]:
        """get_result on a thread: the dict gets ``reply`` (or ``error``) when it ends."""
        box: dict[str, Any] = {}

        def run() -> None:
            try:
                box["reply"] = self.get_result(goal_id, timeout)
            except BaseException as exc:  # the test reads it
                box["error"] = exc

        box["thread"] = threading.Thread(target=run, daemon=True)
        box["thread"].start()
        return box

    def cancel(self, goal_id: bytes | None = None, stamp: tuple[int, int] = (0, 0)) -> Reply:
        """``async_cancel_goal`` (a goal id) or ``async_cancel_all_goals`` (zero id, zero stamp)."""
        uuid = list(goal_id) if goal_id is not None else [0] * 16
        return self.call("cancel_goal", {"goal_info": {"goal_id": {"uuid": uuid}, "stamp": {"sec": stamp[0], "nanosec": stamp[1]}}})

    def feedback_of(self, goal_id: bytes) -> list[tuple[float, dict[str, Any]]]:
        return [(t, m["feedback"]) for t, m, _ in list(self.feedback) if bytes(m["goal_id"]["uuid"]) == goal_id]

    def status_of(self, goal_id: bytes) -> list[int]:
        """Every status this goal had in the status arrays seen, in order."""
        seen = []
        for _, array in list(self.statuses):
            for entry in array["status_list"]:
                if bytes(entry["goal_info"]["goal_id"]["uuid"]) == goal_id:
                    seen.append(entry["status"])
        return seen

    def close(self) -> None:
        self._feedback_sub.undeclare()
        self._status_sub.undeclare()
        for token in self.tokens:
            token.undeclare()


def rate(times: Iterable[float]) -> float:
    """Samples per second over a list of arrival times (0 for fewer than two)."""
    stamps = sorted(times)
    if len(stamps) < 2 or stamps[-1] == stamps[0]:
        return 0.0
    return (len(stamps) - 1) / (stamps[-1] - stamps[0])


class TopicPublisher:
    """A publisher as rmw_zenoh's ``PublisherData`` makes one (its own node here): an MP token, the topic's key with the
    type's hash, each sample CDR with the 33-byte attachment (sequence from 1, ns timestamp, the entity's GID)."""

    def __init__(self, session: zenoh.Session, distro: str, topic: str, typename: str, *, node: str, domain: int = 0) -> None:
        self.interfaces = Interfaces(distro)
        self.typename = typename
        zid = str(session.zid())
        type_hash = self.interfaces.type_hash(typename)
        token = f"@ros2_lv/{domain}/{zid}/0/1/MP/%/%/{node}/{topic.replace('/', '%')}/{dds_type(typename)}/{type_hash}/::,10:,:,:,,"
        self.tokens = [
            session.liveliness().declare_token(f"@ros2_lv/{domain}/{zid}/0/0/NN/%/%/{node}"),
            session.liveliness().declare_token(token),
        ]
        self.gid = bytes(xxhash.xxh3_128_intdigest(token.encode()).to_bytes(16, "little"))
        self.key = f"{domain}/{topic.strip('/')}/{dds_type(typename)}/{type_hash}"
        self._publisher = session.declare_publisher(self.key)
        self._sequence = 0

    def publish(self, message: dict[str, Any]) -> None:
        self._sequence += 1
        self._publisher.put(self.interfaces.serialize(self.typename, message), attachment=attachment(self._sequence, self.gid))

    def close(self) -> None:
        self._publisher.undeclare()
        for token in self.tokens:
            token.undeclare()


def stamped_now(frame: str) -> dict[str, Any]:
    """A std_msgs/Header stamped now in ``frame``."""
    now = time.time()
    return {"stamp": {"sec": int(now), "nanosec": int((now % 1) * 1e9)}, "frame_id": frame}
