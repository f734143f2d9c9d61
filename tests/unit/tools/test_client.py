"""client: latest values, decoded answers, the one sentence when nothing answers, and the tool decorator's exit codes."""

from __future__ import annotations

import argparse
from types import SimpleNamespace

import pytest

from blackmetal.runtime.zenoh_setup import ZenohSettings
from blackmetal.schemas import ConfigError, GatewayHealth, Keys, LinkHealth, Pose, encode, make_pose
from blackmetal.tools import client
from blackmetal.tools.client import Latest, ToolError, decoded_replies, first_reply, query, require_pose, tool

from .fake_session import FakeSession, reply

HEALTH = GatewayHealth(stamp=0.0, control=LinkHealth(state="connected"), log=LinkHealth(state="connected"))


def test_latest_keeps_the_newest_valid_value() -> None:
    session = FakeSession()
    latest = Latest(session, "robot/pose", Pose)  # type: ignore[arg-type]
    assert latest.value is None and latest.age() == float("inf")
    feed = session.subscribers["robot/pose"]
    feed(SimpleNamespace(payload=encode(make_pose(1.0, 2.0, 3.0, 0.0))))
    feed(SimpleNamespace(payload=b"not json"))  # skipped: the previous value stands
    assert latest.wait(0.0).x == 2.0 and latest.count == 1 and latest.age() < 1.0


def test_only_the_answers_that_decode_count() -> None:
    replies = [reply(err=b"no"), SimpleNamespace(ok=SimpleNamespace(payload=b"{bad"), err=None), reply(HEALTH), reply(HEALTH)]
    assert list(decoded_replies(replies, GatewayHealth)) == [HEALTH, HEALTH]
    assert first_reply([reply(err=b"no")], GatewayHealth) is None
    assert query(FakeSession({"h": [reply(HEALTH)]}), "h", GatewayHealth) == HEALTH  # type: ignore[arg-type]


def test_a_missing_service_is_one_sentence_that_says_what_to_check(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(client.time, "sleep", lambda _s: None)
    settings = ZenohSettings(connect=["tcp/127.0.0.1:7447"])
    with pytest.raises(ToolError) as failed:
        require_pose(FakeSession(), Keys(), settings, timeout=0.0)  # type: ignore[arg-type]
    assert str(failed.value) == (
        "no odometry service answered on robot/pose within 0 s (Zenoh: tcp/127.0.0.1:7447). Is `blackmetal up` (or `blackmetal odometry`) running?"
    )


def test_a_tool_ends_in_one_line_with_1_for_its_own_failure_and_2_for_settings(capsys: pytest.CaptureFixture[str]) -> None:
    @tool("demo")
    def fails(args: argparse.Namespace) -> int:
        raise args.error

    assert fails(argparse.Namespace(error=ToolError("nobody answered"))) == 1
    assert fails(argparse.Namespace(error=ConfigError("a bad setting"))) == 2
    assert capsys.readouterr().err == "blackmetal demo: nobody answered\nblackmetal demo: a bad setting\n"
