"""A stand-in for a Zenoh session: puts are recorded, gets answered from a table, subscriptions fed by hand."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import msgspec

from blackmetal.schemas import encode


def reply(message: msgspec.Struct | None = None, err: bytes | None = None) -> SimpleNamespace:
    """A get's reply: an answer that carries ``message``, or an error that carries ``err``."""
    return SimpleNamespace(ok=None if message is None else SimpleNamespace(payload=encode(message)),
                           err=None if err is None else SimpleNamespace(payload=err))  # fmt: skip


@dataclass
class FakeSession:
    #: key -> the replies to a get on it (a callable is asked each time, given the payload).
    answers: dict[str, Any] = field(default_factory=dict)
    puts: list[tuple[str, bytes]] = field(default_factory=list)
    subscribers: dict[str, Callable[[Any], None]] = field(default_factory=dict)
    tokens: list[Any] = field(default_factory=list)

    def __enter__(self) -> FakeSession:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def get(self, key: str, payload: bytes | None = None, **_: object) -> list[Any]:
        answer = self.answers.get(key, [])
        return list(answer(payload) if callable(answer) else answer)

    def declare_publisher(self, key: str, **_: object) -> SimpleNamespace:
        return SimpleNamespace(put=lambda data: self.puts.append((key, bytes(data))))

    def declare_subscriber(self, key: str, callback: Callable[[Any], None] | None = None, **_: object) -> SimpleNamespace:
        if callback is not None:
            self.subscribers[key] = callback
        return SimpleNamespace(undeclare=lambda: None, try_recv=lambda: self.tokens.pop(0) if self.tokens else None)

    def liveliness(self) -> FakeSession:
        return self
