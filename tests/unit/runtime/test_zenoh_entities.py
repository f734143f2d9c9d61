"""The edge's small Zenoh helpers (blackmetal.runtime.zenoh_entities): a sample's last key chunk and payload, a quiet undeclare."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest
import zenoh

from blackmetal.runtime.zenoh_entities import chunk_and_payload, undeclare


def sample(key: str, payload: object) -> Any:
    return SimpleNamespace(key_expr=key, payload=payload)


def test_a_named_input_hands_over_its_last_key_chunk_and_payload() -> None:
    payload = SimpleNamespace(to_bytes=lambda: b'{"linear":{"x":0.1}}')
    assert chunk_and_payload(sample("fleet/a/cmd_vel/nav", payload)) == ("nav", b'{"linear":{"x":0.1}}')


def test_an_unreadable_payload_is_handed_over_empty() -> None:
    assert chunk_and_payload(sample("robot/lock/dock", None)) == ("dock", b"")


def test_a_real_sample_is_read_the_same_way() -> None:
    with zenoh.open(zenoh.Config.from_json5('{mode: "peer", scouting: {multicast: {enabled: false}}}')) as session:
        got: list[tuple[str, bytes]] = []
        subscriber = session.declare_subscriber("t/lock/*", lambda s: got.append(chunk_and_payload(s)))
        session.put("t/lock/dock", b"{}")
        undeclare(subscriber)
    assert got == [("dock", b"{}")]


class Entity:
    def __init__(self, error: Exception | None = None) -> None:
        self.error = error
        self.undeclared = 0

    def undeclare(self) -> None:
        self.undeclared += 1
        if self.error is not None:
            raise self.error


def test_undeclaring_what_a_closing_session_undeclared_already_is_quiet() -> None:
    entity = Entity(zenoh.ZError("already undeclared"))
    undeclare(entity)
    assert entity.undeclared == 1
    undeclare(fresh := Entity())
    assert fresh.undeclared == 1


def test_any_other_failure_to_undeclare_is_raised() -> None:
    with pytest.raises(RuntimeError, match="a bug"):
        undeclare(Entity(RuntimeError("a bug")))
