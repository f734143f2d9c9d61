"""The foxglove-sdk glue: its server, its services, its listener.

Why apart: the SDK calls back on threads of its own; everything here builds the SDK's objects or carries a
client's doing over to the loop (:data:`Handover`), so the host's code runs on the loop only.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any, Protocol

from blackmetal.schemas import BlackmetalError, ConfigError, Param

from .front import INNER_HOST
from .naming import CLIENT_ENCODING
from .settings import FoxgloveSettings

#: A service handler thread waits this much longer than the call's time limit before it gives up on its own.
CALL_MARGIN_S = 1.0


#: A client's doing, carried from the SDK's thread to the loop: the host's method with its arguments bound.
Handover = Callable[[], None]


class ClientEvents(Protocol):
    """What the host does on its loop with what a client did (the listener binds the arguments on the SDK's thread)."""

    def client_advertised(self, client: int, channel: int, topic: str, encoding: str, schema_name: str) -> None: ...
    def client_unadvertised(self, client: int, channel: int) -> None: ...
    def client_published(self, client: int, channel: int, data: bytes) -> None: ...
    def client_subscribed(self, client: int, topic: str, subscribed: bool) -> None: ...


class ServiceFailure(BlackmetalError):
    """Raised in a service handler: the SDK answers the call with a service call failure carrying this text."""


def sdk_listener(
    events: ClientEvents,
    put: Callable[[Handover], None],
    put_subscription: Callable[[Handover], None],
    get_params: Callable[[list[str]], list[Any]],
    set_params: Callable[[int, list[Any]], list[Any]],
) -> Any:
    """A ServerListener that hands every client event over to the view's loop (parameters: from the loop's snapshot)."""
    from foxglove.websocket import ServerListener

    class Listener(ServerListener):
        def on_subscribe(self, client: Any, channel: Any) -> None:
            put_subscription(partial(events.client_subscribed, client.id, channel.topic, True))

        def on_unsubscribe(self, client: Any, channel: Any) -> None:
            put_subscription(partial(events.client_subscribed, client.id, channel.topic, False))

        def on_get_parameters(self, client: Any, param_names: list[str], request_id: str | None = None) -> list[Any]:
            return get_params(param_names)

        def on_set_parameters(self, client: Any, parameters: list[Any], request_id: str | None = None) -> list[Any]:
            return set_params(client.id, parameters)

        def on_client_advertise(self, client: Any, channel: Any) -> None:
            put(partial(events.client_advertised, client.id, channel.id, channel.topic, channel.encoding, channel.schema_name))

        def on_client_unadvertise(self, client: Any, client_channel_id: int) -> None:
            put(partial(events.client_unadvertised, client.id, client_channel_id))

        def on_message_data(self, client: Any, client_channel_id: int, data: bytes) -> None:
            put(partial(events.client_published, client.id, client_channel_id, bytes(data)))

    return Listener()


def foxglove_parameter(param: Param) -> Any:
    """A gateway parameter as the SDK sends it (a double keeps its type even when whole: 0.5 and 1.0 alike)."""
    from foxglove import Parameter, ParameterType

    if param.type == "double" and isinstance(param.value, (int, float)) and not isinstance(param.value, bool):
        return Parameter(param.name, value=float(param.value), type=ParameterType.Float64)
    return Parameter(param.name, value=param.value)


def start_server(settings: FoxgloveSettings, listener: Any = None, services: list[Any] | None = None) -> Any:
    import foxglove
    from foxglove.websocket import Capability

    try:
        return foxglove.start_server(
            name="blackmetal",
            host=INNER_HOST,
            port=0,
            capabilities=[Capability.ClientPublish, Capability.Services, Capability.Parameters],
            server_listener=listener,
            supported_encodings=[CLIENT_ENCODING],
            services=services,
        )
    except Exception as exc:  # the SDK raises its own error with the OS reason
        raise ConfigError(f"cannot start the Foxglove server on {INNER_HOST} ({exc})") from None
