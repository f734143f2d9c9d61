"""estop: the put is repeated until the gateway's health confirms it, on the release key for a release."""

from __future__ import annotations

import argparse

import pytest

from blackmetal.runtime.zenoh_setup import ZenohSettings
from blackmetal.schemas import GatewayHealth, Keys, LinkHealth
from blackmetal.tools import estop
from blackmetal.tools.client import ToolError

from .fake_session import FakeSession, reply


def _health(engaged: bool) -> GatewayHealth:
    return GatewayHealth(stamp=0.0, control=LinkHealth(state="connected"), log=LinkHealth(state="connected"), estop=engaged)


def _run(monkeypatch: pytest.MonkeyPatch, state: str, answers: list[bool]) -> FakeSession:
    session = FakeSession({Keys().health: lambda _payload: [reply(_health(answers.pop(0) if len(answers) > 1 else answers[0]))]})
    monkeypatch.setattr(estop, "connect", lambda args: (Keys(), ZenohSettings(connect=["tcp/127.0.0.1:7447"]), session))
    monkeypatch.setattr(estop, "require_gateway", lambda *args: _health(False))
    monkeypatch.setattr(estop.time, "sleep", lambda _s: None)
    args = argparse.Namespace(state=state, wait=1.0, timeout=0.5)
    if estop.run.__wrapped__(args) != 0:  # type: ignore[attr-defined]
        raise AssertionError("not confirmed")
    return session


def test_an_engage_is_put_until_the_health_says_engaged(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    session = _run(monkeypatch, "on", [False, False, True])
    assert session.puts == [("robot/estop", b'{"engaged": true}')] * 3
    assert capsys.readouterr().out == "blackmetal estop: ENGAGED on robot (confirmed by the gateway)\n"


def test_a_release_goes_on_its_own_key(monkeypatch: pytest.MonkeyPatch) -> None:
    session = _run(monkeypatch, "off", [False])
    assert session.puts == [("robot/estop/release", b'{"engaged": false}')]


def test_no_confirmation_says_what_the_health_said(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(
        ToolError, match=r"did not confirm the e-stop on within 0.5 s \(health still says estop=False; Zenoh: tcp/127.0.0.1:7447\)"
    ):
        _run(monkeypatch, "on", [False])
