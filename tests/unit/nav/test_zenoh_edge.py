"""The navigation's Zenoh edge on an isolated session: the input table feeds the core, the queryables answer with it,
its messages go out routed by type, liveliness is seen whatever the start order, and closing stops a moving robot."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable
from typing import Any

import pytest
import zenoh

from blackmetal.nav.host import NavHost
from blackmetal.nav.params import NavParams
from blackmetal.nav.zenoh_edge import ACTIVE_FOR_S, NavZenoh
from blackmetal.runtime.burst import PutBurst
from blackmetal.schemas import ErrorReport, GatewayParams, Keys, MapPose, NavFeedback, PlanarPose, Twist, Vector3, decode

from .fake_core import FakeNavCore


def collect(session: zenoh.Session, key: str) -> tuple[list[bytes], Any]:
    got: list[bytes] = []
    return got, session.declare_subscriber(key, lambda sample: got.append(bytes(sample.payload.to_bytes())))


async def until(condition: Callable[[], Any], what: str, timeout: float = 5.0) -> None:
    for _ in range(int(timeout / 0.01)):
        if condition():
            return
        await asyncio.sleep(0.01)
    raise AssertionError(f"timed out waiting for {what}")


async def get(session: zenoh.Session, key: str, payload: bytes | None = None) -> list[Any]:
    return await asyncio.to_thread(lambda: list(session.get(key, payload=payload, timeout=5)))


def make(session: zenoh.Session, keys: Keys, **options: Any) -> tuple[NavZenoh, NavHost, FakeNavCore]:
    edge = NavZenoh(session, keys, **options)
    core = FakeNavCore(NavParams(), keys, edge.publish, map_pose=MapPose(stamp=0.0, x=0.0, y=0.0, yaw=0.0))
    return edge, NavHost(core), core  # type: ignore[arg-type]


def test_every_input_of_the_table_reaches_the_core(session: zenoh.Session) -> None:
    keys = Keys("edge/nav")
    gateway_token = session.liveliness().declare_token(keys.alive_gateway)  # alive before nav starts: history shows it

    async def scenario() -> None:
        edge, host, core = make(session, keys)
        edge.attach(host, asyncio.get_running_loop())
        try:
            await until(lambda: core.named("alive"), "the gateway's token, declared before nav")
            assert [call[1:3] for call in core.named("alive")] == [("gateway", True)]
            session.put(keys.pose, b'{"x":1}')
            session.put(keys.health, b"health")
            session.put(keys.driver, b"driver")
            session.put(keys.params, b"gateway params")
            odometry_token = session.liveliness().declare_token(keys.alive_odometry)
            await until(lambda: len(core.calls) >= 6, "every input")
            odometry_token.undeclare()
            await until(lambda: ("odometry", False) in [call[1:3] for call in core.named("alive")], "the odometry's token gone")
            assert [call[1] for call in core.named("pose")] == [b'{"x":1}']
            assert core.named("health")[0][1] == b"health" and core.named("driver")[0][1] == b"driver"
            assert core.named("gateway_params")[0][1] == b"gateway params"
            assert edge.drain() == 0  # one robot: poses came through their callback
        finally:
            edge.close()

    try:
        asyncio.run(scenario())
    finally:
        gateway_token.undeclare()


def test_the_queryables_answer_with_the_core_and_a_bad_payload_with_an_error(session: zenoh.Session) -> None:
    keys = Keys("edge/nav")

    async def scenario() -> None:
        edge, host, core = make(session, keys)
        edge.attach(host, asyncio.get_running_loop())
        try:
            answers = {}
            for key in (keys.nav_goal, keys.nav_move, keys.nav_cancel, keys.nav_result, keys.nav_map_pose, keys.nav_params,
                        keys.nav_params_set, keys.nav_set_pose):  # fmt: skip
                (reply,) = await get(session, key, b'{"x":1,"y":2}')
                assert reply.ok is not None, key
                assert str(reply.ok.key_expr) == key
                answers[key.rpartition("/nav/")[2]] = json.loads(reply.ok.payload.to_bytes())
            assert answers["goal"] == {"accepted": True, "goal_id": "0" * 32, "reason": ""}
            assert answers["move"]["reason"] == "robot e-stopped" and answers["cancel"]["reason"] == "no goal runs"
            assert answers["result"]["found"] is False and answers["map_pose"]["by"] == "settings"
            assert answers["params"]["params"][0]["name"] == "max_speed" and answers["params/set"]["results"] == []
            assert answers["set_pose"]["by"] == "set_pose"
            assert [call[1] for call in core.named("goal")] == [b'{"x":1,"y":2}']
            (bad,) = await get(session, keys.nav_set_pose)  # no payload: the core's PayloadError, replied as an error
            assert bad.err is not None and b"set_pose needs x and y" in bad.err.payload.to_bytes()
            errors = await get(session, keys.errors)  # the core's recent reports
            assert [decode(ErrorReport, r.ok.payload.to_bytes()).reason for r in errors] == ["set_pose needs x and y"]
        finally:
            edge.close()

    asyncio.run(scenario())


def test_messages_are_routed_by_type_and_a_closing_edge_stops_what_it_drove(session: zenoh.Session) -> None:
    keys = Keys("edge/nav")
    routes = {
        key: collect(session, key) for key in (keys.cmd_vel_of("nav"), keys.nav_feedback, keys.nav_map_pose, keys.nav_params, keys.errors)
    }

    async def scenario() -> None:
        edge, host, core = make(session, keys)
        edge.attach(host, asyncio.get_running_loop())
        pose = PlanarPose(x=0.0, y=0.0, yaw=0.0)
        edge.publish(
            NavFeedback(stamp=1.0, goal_id="a" * 32, state="executing", pose=pose, goal=pose, distance_remaining=1.0, eta=2.0, elapsed=0.5)
        )  # type: ignore[arg-type]
        edge.publish(core.map_pose())
        edge.publish(core.params())
        edge.publish(ErrorReport(stamp=1.0, source="nav", key=keys.nav_goal, reason="r"))
        core.driving = True
        session.put(keys.pose, b"{}")  # the fake drives at each pose, as the real core does while a goal runs
        await until(lambda: routes[keys.cmd_vel_of("nav")][0], "nav's command")
        assert edge.moving
        edge.close()  # nav stops while it drives: a zero goes out first

    asyncio.run(scenario())
    for _ in range(500):  # each subscriber's callback runs on a thread of its own
        if len(routes[keys.cmd_vel_of("nav")][0]) >= 2 and all(got for got, _ in routes.values()):
            break
        time.sleep(0.01)
    commands = [decode(Twist, payload) for payload in routes[keys.cmd_vel_of("nav")][0]]
    assert commands == [Twist(linear=Vector3(x=0.1)), Twist()]
    assert decode(NavFeedback, routes[keys.nav_feedback][0][0]).goal_id == "a" * 32
    assert decode(MapPose, routes[keys.nav_map_pose][0][0]).by == "settings"
    assert decode(GatewayParams, routes[keys.nav_params][0][0]).params[0].name == "max_speed"
    assert decode(ErrorReport, routes[keys.errors][0][0]).reason == "r"
    for _, subscriber in routes.values():
        subscriber.undeclare()


def test_a_still_robot_gets_no_zero_when_nav_closes(session: zenoh.Session) -> None:
    keys = Keys("edge/still")
    commands, subscriber = collect(session, keys.cmd_vel_of("nav"))

    async def scenario() -> None:
        edge, host, _core = make(session, keys)
        edge.attach(host, asyncio.get_running_loop())
        edge.publish(Twist(linear=Vector3(x=0.1)))
        edge.publish(Twist())  # the core stopped the robot itself
        assert not edge.moving
        edge.close()

    asyncio.run(scenario())
    for _ in range(500):  # the subscriber's callback runs on a thread of its own
        if len(commands) >= 2:
            break
        time.sleep(0.01)
    time.sleep(0.1)  # and no third, a zero of the close, follows
    subscriber.undeclare()
    assert len(commands) == 2


def test_a_fleet_robot_follows_its_poses_only_while_it_drives(session: zenoh.Session) -> None:
    """Idle, no pose reaches nav; a goal asks for the pose (and the health) first, then follows the poses in a ring the
    loop drains (the newest taken) until ACTIVE_FOR_S after nav last drove or gave feedback."""
    keys = Keys("fleet/r1")
    now = [10.0]
    queryables = [
        session.declare_queryable(keys.pose, lambda q: q.reply(keys.pose, b'{"k":"asked"}')),
        session.declare_queryable(keys.health, lambda q: q.reply(keys.health, b"health now")),
    ]

    async def poses(*ks: int) -> None:
        for k in ks:
            session.put(keys.pose, b'{"k":%d}' % k)
        await asyncio.sleep(0.05)

    async def scenario() -> None:
        edge, host, core = make(session, keys, burst=PutBurst(), clock=lambda: now[0])
        edge.attach(host, asyncio.get_running_loop(), ring=True)
        taken = lambda: [call[1] for call in core.named("pose")]  # noqa: E731
        try:
            await poses(0, 1)
            assert edge.drain() == 0 and taken() == []  # idle: nothing followed
            (reply,) = await get(session, keys.nav_goal, b"{}")
            assert reply.ok is not None
            assert [call[0] for call in core.calls] in (["health", "pose", "goal"], ["pose", "health", "goal"])
            assert taken() == [b'{"k":"asked"}']  # the pose asked for, before the goal
            await poses(2, 3)
            assert edge.drain() == 2 and taken()[-1] == b'{"k":3}' and b'{"k":2}' not in taken()  # following: the newest
            now[0] += ACTIVE_FOR_S / 2
            edge.publish(Twist(linear=Vector3(x=0.1)))  # nav drives: it goes on following
            now[0] += ACTIVE_FOR_S / 2
            await poses(4)
            assert edge.drain() == 1 and taken()[-1] == b'{"k":4}'
            now[0] += ACTIVE_FOR_S  # nothing driven or fed back since: it stops following
            await poses(5)
            assert edge.drain() == 0
            await poses(6)
            assert edge.drain() == 0 and taken()[-1] == b'{"k":4}'
            (reply,) = await get(session, keys.nav_set_pose, b'{"x":1,"y":2}')  # a set-pose asks for the pose too
            assert reply.ok is not None and taken()[-1] == b'{"k":"asked"}' and len(core.named("health")) == 1
        finally:
            edge.close()
        assert edge.drain() == 0  # closed: nothing drained from an undeclared subscriber

    try:
        asyncio.run(scenario())
    finally:
        for queryable in queryables:
            queryable.undeclare()


def test_a_bug_in_a_handler_goes_to_the_host(session: zenoh.Session) -> None:
    keys = Keys("edge/bug")

    async def scenario() -> None:
        edge, host, _core = make(session, keys)
        failures: list[BaseException] = []
        host.supervised = True
        host.fail = failures.append  # type: ignore[method-assign]
        edge.attach(host, asyncio.get_running_loop())
        try:
            replies = await get(session, keys.nav_goal, b"bug")
            assert not [r for r in replies if r.ok is not None]  # no answer to a goal whose handling failed
            await until(lambda: failures, "the failure")
            assert "a bug in the goal's handling" in str(failures[0])
        finally:
            edge.close()

    asyncio.run(scenario())


@pytest.mark.parametrize("role", ["gateway", "odometry"])
def test_a_service_that_leaves_is_seen_gone(session: zenoh.Session, role: str) -> None:
    keys = Keys(f"edge/{role}")

    async def scenario() -> None:
        edge, host, core = make(session, keys)
        edge.attach(host, asyncio.get_running_loop())
        try:
            token = session.liveliness().declare_token(keys.alive(role))
            await until(lambda: core.named("alive"), "the token")
            token.undeclare()
            await until(lambda: len(core.named("alive")) == 2, "its end")
            assert [call[1:3] for call in core.named("alive")] == [(role, True), (role, False)]
        finally:
            edge.close()

    asyncio.run(scenario())


def test_a_gateway_that_appears_is_asked_for_its_health_and_parameters(session: zenoh.Session) -> None:
    """Its health comes each second and its parameters only on a change: nav, started after it, asks at once."""
    keys = Keys("edge/ask")
    answers = {keys.health: b"health now", keys.params: b"params now"}
    queryables = [session.declare_queryable(key, lambda q, key=key: q.reply(key, answers[key])) for key in answers]

    async def scenario() -> None:
        edge, host, core = make(session, keys)
        edge.attach(host, asyncio.get_running_loop())
        try:
            await asyncio.sleep(0.1)
            assert not core.named("health")  # no gateway yet: nothing asked
            token = session.liveliness().declare_token(keys.alive_gateway)
            await until(lambda: core.named("health") and core.named("gateway_params"), "the answers")
            assert core.named("health")[0][1] == b"health now" and core.named("gateway_params")[0][1] == b"params now"
            token.undeclare()
        finally:
            edge.close()
        edge.ask(keys.health, lambda payload: None)  # after the close: nothing happens, nothing raises

    try:
        asyncio.run(scenario())
    finally:
        for queryable in queryables:
            queryable.undeclare()


def test_a_goal_is_handled_after_the_gateways_health_it_asks_for(session: zenoh.Session) -> None:
    """Health comes once a second: a link that came up since would still read down. A goal (and a move) asks first."""
    keys = Keys("edge/fresh")
    asked: list[int] = []

    def health(query: zenoh.Query) -> None:
        asked.append(1)
        query.reply(keys.health, b"health now")

    queryable = session.declare_queryable(keys.health, health)

    async def scenario() -> None:
        edge, host, core = make(session, keys)
        edge.attach(host, asyncio.get_running_loop())
        try:
            for key in (keys.nav_goal, keys.nav_move):
                (reply,) = await get(session, key, b"{}")
                assert reply.ok is not None
            order = [call[0] for call in core.calls]
            assert order == ["health", "goal", "health", "move"] and len(asked) == 2
            (reply,) = await get(session, keys.nav_cancel, b"{}")  # a cancel never waits for anything
            assert reply.ok is not None and len(asked) == 2
        finally:
            edge.close()

    try:
        asyncio.run(scenario())
    finally:
        queryable.undeclare()


def test_a_goal_asks_for_the_health_only_when_the_last_said_the_robot_could_not_drive(session: zenoh.Session) -> None:
    """An e-stop and a lost link are published at once; a link that came up, within a second: only then is it asked."""
    from blackmetal.schemas import GatewayHealth, LinkHealth, encode

    keys = Keys("edge/ready")
    asked: list[int] = []

    def health(ready: bool, estop: bool = False) -> bytes:
        state = "connected" if ready else "down"
        return encode(GatewayHealth(stamp=1.0, control=LinkHealth(state), log=LinkHealth(state), estop=estop))

    queryable = session.declare_queryable(keys.health, lambda q: (asked.append(1), q.reply(keys.health, health(True))))

    async def scenario() -> None:
        edge, host, core = make(session, keys)
        edge.attach(host, asyncio.get_running_loop())
        try:
            await get(session, keys.nav_goal, b"{}")
            assert len(asked) == 1  # nothing heard yet: asked
            await get(session, keys.nav_goal, b"{}")
            assert len(asked) == 1  # the answer said it can drive: not asked again
            session.put(keys.health, health(True, estop=True))
            await until(lambda: len(core.named("health")) == 2, "the e-stop's health")
            await get(session, keys.nav_move, b"{}")
            assert len(asked) == 2  # engaged at the last word: asked (it may have been released since)
            session.put(keys.health, b"not json")
            await until(lambda: len(core.named("health")) == 4, "the bad health")
            await get(session, keys.nav_goal, b"{}")
            assert len(asked) == 3 and [c[0] for c in core.calls].count("goal") == 3
        finally:
            edge.close()

    try:
        asyncio.run(scenario())
    finally:
        queryable.undeclare()


def test_command_hz_sends_the_newest_command_at_its_turn_and_a_stop_at_once(session: zenoh.Session) -> None:
    keys = Keys("edge/paced")
    commands, subscriber = collect(session, keys.cmd_vel_of("nav"))

    def twist(v: float) -> Twist:
        return Twist(linear=Vector3(x=v))

    async def scenario() -> None:
        edge = NavZenoh(session, keys, command_hz=10.0)  # one each 0.1 s at most
        edge.publish(twist(0.1))  # its turn: at once
        edge.publish(twist(0.2))  # waits...
        edge.publish(twist(0.3))  # ...replaced by the newest
        await asyncio.sleep(0.02)
        assert len(commands) == 1
        await asyncio.sleep(0.15)
        assert [decode(Twist, c).linear.x for c in commands] == [0.1, 0.3]  # the newest, at its turn
        edge.publish(twist(0.4))  # waits for its turn...
        edge.publish(Twist())  # ...a stop does not: at once, and the waiting one is dropped
        await asyncio.sleep(0.15)
        assert [decode(Twist, c).linear.x for c in commands] == [0.1, 0.3, 0.0] and not edge.moving
        edge.publish(twist(0.5))
        edge.publish(twist(0.6))
        edge.close()  # a command still waiting is dropped, and the robot gets a zero
        await asyncio.sleep(0.15)

    asyncio.run(scenario())
    for _ in range(100):
        if len(commands) >= 5:
            break
        time.sleep(0.01)
    subscriber.undeclare()
    assert [decode(Twist, c).linear.x for c in commands] == [0.1, 0.3, 0.0, 0.5, 0.0]
