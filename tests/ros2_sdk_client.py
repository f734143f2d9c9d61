"""A ROS 2 node made with zenoh-ros2-sdk (ROBOTIS, from PyPI): the independent rmw_zenoh client of tests/integration/test_ros2_sdk.py.

Runs in the SDK's own virtualenv, never in ours (it imports zenoh_ros2_sdk
and the standard library only), as ``python ros2_sdk_client.py ROUTER_PORT
INTERFACES_DIR``. It is a peer of the rmw_zenoh router on 127.0.0.1:PORT
with the SDK's own session config (rmw_zenoh's), and reads its message
definitions from INTERFACES_DIR (``<pkg>/msg/<Type>.msg``) instead of
cloning them from GitHub.

It takes one JSON command a line on stdin and answers one JSON line on
stdout (logs go to stderr):

* ``{"op": "subscribe", "topic": "/odom", "type": "nav_msgs/msg/Odometry", "transient_local": false}``
  -> ``{"ok": true, "key": <its key expression>}``; from then on it counts the samples;
* ``{"op": "received", "topic": "/odom"}`` -> ``{"count": N, "first_after_s": S, "last": {message as JSON}}``;
* ``{"op": "publish", "topic": "/cmd_vel", "type": "geometry_msgs/msg/Twist", "message": {...},
  "stamp": "now" (optional: header.stamp set to the time of each sample), "rate_hz": 10, "duration_s": 1.5}``
  -> ``{"ok": true, "sent": N, "key": ...}`` once done;
* ``{"op": "call", "service": "/blackmetal/set_parameters", "type": "rcl_interfaces/srv/SetParameters",
  "request": {...}}`` -> ``{"ok": true, "response": {...}, "elapsed_s": S, "started": T, "key": ...}`` (the SDK's service client; T its
  time.monotonic() as the call began, the same clock as the test's);
* ``{"op": "quit"}``.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from typing import Any

from zenoh_ros2_sdk import ROS2Publisher, ROS2ServiceClient, ROS2Subscriber, ZenohSession
from zenoh_ros2_sdk.message_registry import get_message_class, get_registry
from zenoh_ros2_sdk.qos import QosDurability, QosProfile

PORT = int(sys.argv[1])
get_registry(sys.argv[2])  # the message definitions: before anything asks the registry
LOCK = threading.Lock()
received: dict[str, dict[str, Any]] = {}
publishers: dict[tuple[str, str], ROS2Publisher] = {}
subscribers: list[ROS2Subscriber] = []
clients: dict[tuple[str, str], ROS2ServiceClient] = {}


def as_json(value: Any) -> Any:
    """A rosbags message (dataclass, numpy array) as plain JSON values."""
    if hasattr(value, "__dataclass_fields__"):
        return {name: as_json(getattr(value, name)) for name in value.__dataclass_fields__ if name != "__msgtype__"}
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [as_json(v) for v in value]
    return value


def build(ros_type: str, fields: dict[str, Any]) -> Any:
    """A message of ``ros_type`` from JSON fields (missing ones zero), nested messages built from the type store's definitions."""
    from rosbags.typesys.base import Nodetype  # the SDK's own dependency, in its virtualenv

    store = ZenohSession.get_instance().store
    if ros_type not in store.fielddefs:
        get_message_class(ros_type)  # loads the type and its dependencies into the SDK's store
    _, definition = store.fielddefs[ros_type]
    args: dict[str, Any] = {}
    for name, (kind, rest) in definition:
        value = fields.get(name)
        if kind == Nodetype.NAME:
            args[name] = build(rest, value or {})
        elif kind == Nodetype.BASE:
            args[name] = value if value is not None else ("" if rest[0] == "string" else 0)
        else:  # an array or a sequence: of messages, of strings, or of numbers (numpy, as rosbags serializes them)
            import numpy as np

            (inner_kind, inner), _ = rest
            items = list(value or [])
            if inner_kind == Nodetype.NAME:
                args[name] = [build(inner, item) for item in items]
            elif inner[0] == "string":
                args[name] = [str(item) for item in items]
            else:
                dtypes = {
                    "bool": np.bool_,
                    "byte": np.uint8,
                    "char": np.uint8,
                    "uint8": np.uint8,
                    "float32": np.float32,
                    "float64": np.float64,
                }
                args[name] = np.asarray(items, dtype=dtypes.get(inner[0], np.int64 if inner[0].startswith("int") else np.uint64))
    return store.types[ros_type](**args)


def alias_same_package_types(typename: str) -> None:
    """zenoh-ros2-sdk 0.1.8 reads a .srv's same-package type (``ListParametersResult`` in rcl_interfaces'
    ListParameters.srv) as ``rcl_interfaces/srv/msg/ListParametersResult``, which its store never holds, so the
    request or the response cannot be (de)serialized (its type hash, computed from the text, is right). Register
    each such name as the package's message of that name, as rosidl resolves it."""
    from rosbags.typesys.base import Nodetype

    store = ZenohSession.get_instance().store
    for _, desc in store.fielddefs[typename][1]:
        while desc[0] in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            desc = desc[1][0]
        if desc[0] != Nodetype.NAME or desc[1] in store.fielddefs:
            continue
        real = desc[1].replace("/srv/msg/", "/msg/")
        if real not in store.fielddefs:
            get_message_class(real)
        store.register({desc[1]: store.fielddefs[real]})
        alias_same_package_types(real)


def call(command: dict[str, Any]) -> dict[str, Any]:
    """One service call through the SDK's ROS2ServiceClient (its own keys, hash, attachment); the response as JSON."""
    service, srv_type = command["service"], command["type"]
    client = clients.get((service, srv_type))
    if client is None:
        client = ROS2ServiceClient(service, srv_type, node_name="sdk_param_client", router_port=PORT, timeout=10.0)
        alias_same_package_types(client.request_store_type)
        alias_same_package_types(client.response_store_type)
        clients[(service, srv_type)] = client
        time.sleep(0.5)  # its token and querier reach the router first
    request = build(client.request_store_type, command.get("request", {}))
    fields = {field: getattr(request, field) for field in request.__dataclass_fields__ if field != "__msgtype__"}
    started = time.monotonic()
    response = client.call(**fields)
    elapsed = time.monotonic() - started
    if response is None:
        return {"error": f"no response from {service} within the SDK's timeout", "key": client.keyexpr}
    return {"ok": True, "response": as_json(response), "elapsed_s": elapsed, "started": started, "key": client.keyexpr}


def subscribe(command: dict[str, Any]) -> dict[str, Any]:
    topic = command["topic"]
    started = time.monotonic()
    entry: dict[str, Any] = {"count": 0, "first_after_s": None, "last": None}
    with LOCK:
        received[topic] = entry

    def on_message(message: Any) -> None:
        with LOCK:
            entry["count"] += 1
            if entry["first_after_s"] is None:
                entry["first_after_s"] = time.monotonic() - started
            entry["last"] = as_json(message)

    qos = QosProfile(durability=QosDurability.TRANSIENT_LOCAL, history_depth=1) if command.get("transient_local") else None
    subscriber = ROS2Subscriber(
        topic=topic, msg_type=command["type"], callback=on_message, node_name="sdk_listener", router_port=PORT, qos=qos
    )
    subscribers.append(subscriber)
    return {"ok": True, "key": subscriber.keyexpr}


def publish(command: dict[str, Any]) -> dict[str, Any]:
    topic, ros_type = command["topic"], command["type"]
    publisher = publishers.get((topic, ros_type))
    if publisher is None:
        publisher = ROS2Publisher(topic=topic, msg_type=ros_type, node_name="sdk_teleop", router_port=PORT)
        publishers[(topic, ros_type)] = publisher
        time.sleep(0.5)  # the token and the publisher's declaration reach the router first
    period = 1.0 / float(command.get("rate_hz", 10))
    end = time.monotonic() + float(command.get("duration_s", 1.5))
    sent = 0
    while time.monotonic() < end:
        fields = json.loads(json.dumps(command["message"]))
        if command.get("stamp") == "now":
            now = time.time()
            fields.setdefault("header", {})["stamp"] = {"sec": int(now), "nanosec": int((now % 1) * 1e9)}
        message = build(ros_type, fields)
        publisher.publish(**{name: getattr(message, name) for name in message.__dataclass_fields__ if name != "__msgtype__"})
        sent += 1
        time.sleep(period)
    return {"ok": True, "sent": sent, "key": publisher.keyexpr if hasattr(publisher, "keyexpr") else None}


def main() -> None:
    ZenohSession.get_instance("127.0.0.1", PORT)
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        command = json.loads(line)
        op = command["op"]
        try:
            if op == "quit":
                break
            if op == "subscribe":
                answer = subscribe(command)
            elif op == "received":
                with LOCK:
                    answer = dict(received.get(command["topic"], {"count": 0, "first_after_s": None, "last": None}))
            elif op == "publish":
                answer = publish(command)
            elif op == "call":
                answer = call(command)
            else:
                answer = {"error": f"unknown op {op!r}"}
        except Exception as exc:  # the test reads the reason
            answer = {"error": f"{type(exc).__name__}: {exc}"}
        print(json.dumps(answer), flush=True)
    for subscriber in subscribers:
        subscriber.close()
    for publisher in publishers.values():
        publisher.close()
    for client in clients.values():
        client.close()
    ZenohSession.get_instance().close()


if __name__ == "__main__":
    main()
