"""The foxglove-sdk glue: the SDK's threads hand every client doing to the loop; parameters keep their type; the server starts."""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

from blackmetal.foxglove.sdk import foxglove_parameter, sdk_listener, start_server
from blackmetal.foxglove.settings import FoxgloveSettings
from blackmetal.schemas import Param


class Events:
    def __init__(self) -> None:
        self.seen: list[tuple[Any, ...]] = []

    def client_advertised(self, client: int, channel: int, topic: str, encoding: str, schema_name: str) -> None:
        self.seen.append(("advertised", client, channel, topic, encoding, schema_name))

    def client_unadvertised(self, client: int, channel: int) -> None:
        self.seen.append(("unadvertised", client, channel))

    def client_published(self, client: int, channel: int, data: bytes) -> None:
        self.seen.append(("published", client, channel, data))

    def client_subscribed(self, client: int, topic: str, subscribed: bool) -> None:
        self.seen.append(("subscribed", client, topic, subscribed))


def test_the_listener_binds_each_doing_on_the_sdks_thread_and_hands_it_over() -> None:
    events, handed, subscriptions = Events(), list[Callable[[], None]](), list[Callable[[], None]]()
    listener = sdk_listener(events, handed.append, subscriptions.append, lambda names: ["get", names], lambda c, p: ["set", c, p])
    client = SimpleNamespace(id=4)
    channel = SimpleNamespace(id=9, topic="/cmd_vel", encoding="json", schema_name="geometry_msgs/msg/Twist")
    listener.on_client_advertise(client, channel)
    listener.on_message_data(client, 9, memoryview(b"{}"))
    listener.on_client_unadvertise(client, 9)
    listener.on_subscribe(client, SimpleNamespace(topic="/pose"))
    listener.on_unsubscribe(client, SimpleNamespace(topic="/pose"))
    assert not events.seen, "nothing runs on the SDK's thread"
    for call in [*handed, *subscriptions]:
        call()
    assert events.seen == [
        ("advertised", 4, 9, "/cmd_vel", "json", "geometry_msgs/msg/Twist"),
        ("published", 4, 9, b"{}"),
        ("unadvertised", 4, 9),
        ("subscribed", 4, "/pose", True),
        ("subscribed", 4, "/pose", False),
    ]
    assert listener.on_get_parameters(client, ["a"]) == ["get", ["a"]] and listener.on_set_parameters(client, [1]) == ["set", 4, [1]]


def test_a_double_stays_a_double_when_whole() -> None:
    whole = foxglove_parameter(Param("max_wheel_speed", "double", 1, min=0.0, max=2.0))
    assert whole.name == "max_wheel_speed" and whole.get_value() == 1.0 and isinstance(whole.get_value(), float)
    assert foxglove_parameter(Param("robot", "string", "127.0.0.1:665", read_only=True)).get_value() == "127.0.0.1:665"
    assert foxglove_parameter(Param("sources.nav.priority", "integer", 10)).get_value() == 10


def test_the_server_listens_on_a_free_loopback_port() -> None:
    server = start_server(FoxgloveSettings(port=0))
    try:
        assert server.port > 0
    finally:
        server.stop()
