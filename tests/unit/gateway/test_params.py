"""The gateway's live parameters, on the fake-clock bench: a set takes effect at once, a refusal says why and changes nothing."""

from __future__ import annotations

import json
import time

import pytest
from helpers import wait_for
from integration.test_safety_e2e import KEYS, VELOCITY, Rig, make, rig_factory  # noqa: F401 (a fixture)
from rogue_robot import Behaviour

from blackmetal.schemas import ErrorReport, GatewayParams, ParamsSetReply, decode
from unit.gateway.test_core import Bench


def set_params(bench: Bench, **values: object) -> dict[str, str]:
    """Set ``values`` through the core's key handler; each name -> '' when set, else the reason."""
    reply = bench.conn.on_params_set(json.dumps({"values": values}).encode(), bench.t)
    assert not isinstance(reply, str), reply
    bench.settle()
    return {result.name: ("" if result.successful else result.reason) for result in reply.results}


def table(bench: Bench) -> dict[str, object]:
    return {param.name: param.value for param in bench.conn.params_now().params}


def test_a_lower_speed_limit_slows_a_robot_that_is_driving_at_once() -> None:
    bench = Bench(cmd_timeout=0.0)
    bench.connect()
    bench.cmd(b'{"linear":{"x":0.6}}')
    assert bench.velocity()[-1][1:] == pytest.approx((0.6, 0.6))
    assert set_params(bench, max_wheel_speed=0.3) == {"max_wheel_speed": ""}
    assert bench.velocity()[-1][1:] == pytest.approx((0.3, 0.3))  # the next command out, with no new cmd_vel
    bench.cmd(b'{"linear":{"x":0.2},"angular":{"z":2.0}}')  # an arc beyond the new limit keeps its curvature
    left, right = bench.velocity()[-1][1:]
    assert max(abs(left), abs(right)) == pytest.approx(0.3) and right > left
    published = [event for event in bench.events if isinstance(event, GatewayParams)]
    assert published and published[-1].changed == ["max_wheel_speed"] and table(bench)["max_wheel_speed"] == 0.3


@pytest.mark.parametrize(
    ("name", "value", "says"),
    [
        ("max_wheel_speed", 5.0, "within 0.01..0.8"),
        ("max_wheel_speed", "fast", "takes a number"),
        ("max_wheel_speed", True, "takes a number"),
        ("cmd_timeout", 0.0, "refused on a running gateway"),
        ("cmd_timeout", 0.01, "at least 0.05 s"),
        ("cmd_timeout", 600.0, "within 0..60"),
        ("sources.teleop.priority", 1.5, "takes an integer"),
        ("sources.teleop.priority", 300, "within 0..255"),
        ("wheel_separation", 0.6, "read-only on a running gateway"),
        ("max_speed", 0.3, "no parameter 'max_speed'"),
    ],
)
def test_a_refused_value_says_why_is_reported_and_changes_nothing(name: str, value: object, says: str) -> None:
    bench = Bench()
    bench.connect()
    before = table(bench)
    reasons = set_params(bench, **{name: value})
    assert says in reasons[name]
    assert table(bench) == before
    reports = [event for event in bench.events if isinstance(event, ErrorReport)]
    assert reports and reports[-1].key == "robot/gateway/params/set" and says in reports[-1].reason
    assert not [event for event in bench.events if isinstance(event, GatewayParams)]  # nothing changed, nothing published


def test_each_value_is_set_on_its_own() -> None:
    bench = Bench()
    bench.connect()
    reasons = set_params(bench, max_wheel_speed=0.5, cmd_timeout=-1.0, linear_accel=0.5)
    assert reasons["max_wheel_speed"] == "" and reasons["linear_accel"] == "" and "within" in reasons["cmd_timeout"]
    now = table(bench)
    assert now["max_wheel_speed"] == 0.5 and now["linear_accel"] == 0.5 and now["cmd_timeout"] == 0.5


def test_a_new_priority_hands_the_robot_over_at_once() -> None:
    bench = Bench(cmd_timeout=0.0, source=["teleop:100:5", "nav:10:5"])
    bench.connect()
    bench.conn.on_cmd_vel("teleop", b'{"linear":{"x":0.1}}', bench.t)
    bench.conn.on_cmd_vel("nav", b'{"linear":{"x":0.4}}', bench.t)
    bench.settle()
    bench.run(0.01)
    assert bench.velocity()[-1][1:] == pytest.approx((0.1, 0.1))  # teleop outranks nav
    assert set_params(bench, **{"sources.nav.priority": 200}) == {"sources.nav.priority": ""}
    bench.run(0.01)
    assert bench.conn.arbiter.active == "nav"
    assert bench.velocity()[-1][1:] == pytest.approx((0.4, 0.4))


def test_the_table_shows_the_fixed_values_read_only_and_the_live_ones_bounded() -> None:
    bench = Bench(wheel_separation=0.45, lock=["pause:200"])
    params = {param.name: param for param in bench.conn.params_now().params}
    assert params["wheel_separation"].read_only and params["wheel_separation"].value == 0.45
    assert params["locks.pause.priority"].read_only and params["locks.pause.priority"].value == 200
    live = params["max_wheel_speed"]
    assert not live.read_only and live.type == "double" and (live.min, live.max) == (0.01, 0.8)
    assert params["sources.teleop.priority"].type == "integer" and params["sources.teleop.priority"].value == 100


def test_a_payload_that_is_not_a_params_set_is_refused_and_reported() -> None:
    bench = Bench()
    reason = bench.conn.on_params_set(b'{"max_wheel_speed": 0.3}', bench.t)
    assert isinstance(reason, str) and "unknown field `max_wheel_speed`" in reason and '{"values"' in reason
    reports = bench.conn.take_events()
    assert any(isinstance(event, ErrorReport) and '{"values"' in event.reason for event in reports)
    assert decode(GatewayParams, b'{"stamp": 1.0, "params": []}').changed == []


@pytest.mark.integration
def test_a_set_over_zenoh_reaches_the_robots_wire_and_is_published(rig_factory: list[Rig]) -> None:  # noqa: F811
    """The gateway process: a get on gateway/params/set slows the robot with no new command; a bad payload gets an error reply."""
    rig = make(rig_factory, Behaviour(), "--cmd-timeout", "0")
    published: list[GatewayParams] = []
    rig.session.declare_subscriber(KEYS.params, lambda s: published.append(decode(GatewayParams, s.payload.to_bytes())))
    rig.drive(0.6)
    start = time.monotonic()
    (reply,) = rig.session.get(KEYS.params_set, payload=json.dumps({"values": {"max_wheel_speed": 0.3}}), timeout=5)
    assert reply.ok is not None
    answer = decode(ParamsSetReply, reply.ok.payload.to_bytes())
    assert [(r.name, r.successful) for r in answer.results] == [("max_wheel_speed", True)]
    (arrival, _), *_ = wait_for(lambda: [c for c in rig.robot.commands(VELOCITY, since=start) if c[1] == (0.3, 0.3)],
                                what="the robot's command at the new limit")  # fmt: skip
    print(f"max_wheel_speed 0.6 -> 0.3: at the robot {1000 * (arrival - start):.1f} ms after the get")
    wait_for(lambda: published and published[-1].changed == ["max_wheel_speed"], what="the new table published")
    (current,) = rig.session.get(KEYS.params, timeout=5)
    assert current.ok is not None
    values = {p.name: p.value for p in decode(GatewayParams, current.ok.payload.to_bytes()).params}
    assert values["max_wheel_speed"] == 0.3
    (bad,) = rig.session.get(KEYS.params_set, payload=b'{"max_wheel_speed": 0.3}', timeout=5)
    assert bad.err is not None and "values" in bad.err.payload.to_bytes().decode()
    wait_for(lambda: any('"values"' in e for e in rig.errors), what="the refusal reported on errors")


@pytest.mark.integration
def test_blackmetal_params_lists_and_sets_and_says_what_it_refused(rig_factory: list[Rig]) -> None:  # noqa: F811
    import subprocess
    import sys

    rig = make(rig_factory, Behaviour())
    base = [sys.executable, "-m", "blackmetal", "params", "-e", f"tcp/127.0.0.1:{rig.zport}"]
    listed = subprocess.run(base, capture_output=True, text=True, timeout=30)
    assert listed.returncode == 0, listed.stderr
    rows = {line.split()[0]: line for line in listed.stdout.splitlines()}
    assert "0.01 .. 0.8" in rows["max_wheel_speed"] and "read-only" in rows["wheel_separation"]
    changed = subprocess.run([*base, "max_wheel_speed=0.4", "cmd_timeout=0"], capture_output=True, text=True, timeout=30)
    assert changed.returncode == 1
    assert changed.stdout.splitlines()[0] == "max_wheel_speed: set"
    assert changed.stdout.splitlines()[1].startswith("cmd_timeout: refused: cmd_timeout 0 (no deadman) is refused")
    assert rig.health() is not None
    bad = subprocess.run([*base, "max_wheel_speed"], capture_output=True, text=True, timeout=30)
    assert bad.returncode == 1 and bad.stderr.count("\n") == 1 and "NAME=VALUE" in bad.stderr
