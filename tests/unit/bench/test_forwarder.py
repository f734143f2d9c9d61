"""The minimal forwarder: a JSON twist on cmd_vel becomes one set-velocity request at the robot's socket."""

from __future__ import annotations

import socket
import sys
from types import SimpleNamespace
from typing import Any

import pytest

from blackmetal import robot_model, wire
from blackmetal.bench import forwarder


def test_a_twist_becomes_one_wire_request(monkeypatch: pytest.MonkeyPatch) -> None:
    subscribed: list[str] = []
    kinds: list[bool] = []

    def callback_handler(function: Any, *, indirect: bool = True) -> Any:
        kinds.append(indirect)
        return function

    class Session:
        def __enter__(self) -> Session:
            return self

        def __exit__(self, *exc: object) -> None:
            return None

        def declare_subscriber(self, key: str, callback: Any) -> None:
            subscribed.append(key)
            callback(SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: b'{"linear":{"x":0.2},"angular":{"z":0.5}}')))

    handlers = SimpleNamespace(Callback=callback_handler)
    monkeypatch.setitem(sys.modules, "zenoh", SimpleNamespace(open=lambda conf: Session(), Sample=object, handlers=handlers))
    monkeypatch.setattr(forwarder, "_zenoh_conf", lambda listen: None)
    monkeypatch.setattr(forwarder, "announce_ready", lambda name: None)
    monkeypatch.setattr(forwarder, "threading", SimpleNamespace(Event=lambda: SimpleNamespace(wait=lambda: None)))
    with socket.create_server(("127.0.0.1", 0)) as server:
        forwarder.forwarder_main(0, server.getsockname()[1])
        conn, _ = server.accept()
        with conn:
            received = conn.recv(4096)
    wheels, _ = robot_model.twist_to_wheels(0.2, 0.5, robot_model.WHEEL_SEPARATION, robot_model.MAX_WHEEL_SPEED)
    assert subscribed == ["robot/cmd_vel"]
    assert kinds == [False], "the forwarder runs on Zenoh's own thread, as the issue defines the floor"
    assert received == wire.encode_request(wire.set_velocity(left=wheels.left, right=wheels.right))
