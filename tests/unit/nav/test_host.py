"""The navigation's host: every input reaches the core stamped with the clock, the core's tick runs at its deadline,
and a bug ends a fleet robot's run (supervised) for its restart while a single robot's service goes on."""

from __future__ import annotations

import asyncio

import pytest

from blackmetal.nav.host import NavHost
from blackmetal.nav.params import NavParams
from blackmetal.schemas import Keys, MapPose, PayloadError

from .fake_core import FakeNavCore


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def host(*, supervised: bool = False, loop_clock: bool = False) -> tuple[NavHost, FakeNavCore, list[object], Clock]:
    """A host of a fake core on a hand-moved clock, or (``loop_clock``) on the running loop's."""
    out: list[object] = []
    core = FakeNavCore(NavParams(), Keys(), out.append, map_pose=MapPose(stamp=0.0, x=0.0, y=0.0, yaw=0.0))
    clock = Clock()
    time = asyncio.get_running_loop().time if loop_clock else clock
    return NavHost(core, time, supervised=supervised), core, out, clock  # type: ignore[arg-type]


def test_each_input_reaches_the_core_with_now() -> None:
    nav, core, _out, clock = host()
    nav.on_pose(b"p")
    clock.now = 101.0
    nav.on_health(b"h")
    nav.on_driver(b"d")
    nav.on_gateway_params(b"g")
    nav.on_alive("odometry", False)
    assert core.calls == [
        ("pose", b"p", 100.0),
        ("health", b"h", 101.0),
        ("driver", b"d", 101.0),
        ("gateway_params", b"g", 101.0),
        ("alive", "odometry", False, 101.0),
    ]


def test_queries_are_answered_by_the_core_and_a_bad_set_pose_stays_a_payload_error() -> None:
    nav, core, _out, _clock = host()
    assert nav.on_goal(b"{}").accepted
    assert nav.on_move(None).reason == "robot e-stopped"
    assert nav.on_cancel(b"").reason == "no goal runs"
    assert not nav.on_result(None).found
    assert nav.on_params_set(b"{}").params.params[0].name == "max_speed"
    assert nav.params().params[0].value == 0.3 and nav.map_pose().by == "settings"
    with pytest.raises(PayloadError):
        nav.on_set_pose(None)
    assert nav.on_set_pose(b'{"x":1,"y":2}').by == "set_pose"
    assert [call[0] for call in core.calls] == ["goal", "move", "cancel", "result", "params_set", "set_pose", "set_pose"]


def test_the_tick_runs_first_at_start_then_at_the_cores_deadline() -> None:
    async def scenario() -> None:
        nav, core, out, _ = host(loop_clock=True)
        stop = asyncio.Event()
        running = asyncio.ensure_future(nav.run(stop))
        await asyncio.sleep(0.01)
        assert len(core.ticks) == 1 and [type(m).__name__ for m in out] == ["MapPose", "GatewayParams"]  # the first tick
        core.deadline = nav.clock() + 0.05
        nav.on_pose(b"p")  # an input pokes the timer: the new deadline is kept
        await asyncio.sleep(0.2)
        assert len(core.ticks) == 2 and core.ticks[1] >= core.ticks[0] + 0.05
        stop.set()
        await asyncio.wait_for(running, 2)

    asyncio.run(scenario())


def test_a_supervised_host_ends_its_run_with_the_failure_of_a_tick() -> None:
    async def scenario() -> None:
        nav, core, _out, _ = host(supervised=True, loop_clock=True)

        def broken(now: float) -> None:
            raise RuntimeError("a bug in the tick")

        running = asyncio.ensure_future(nav.run(asyncio.Event()))
        await asyncio.sleep(0.01)
        core.tick = broken  # type: ignore[method-assign]
        core.deadline = nav.clock()
        nav.on_pose(b"p")
        with pytest.raises(RuntimeError, match="a bug in the tick"):
            await asyncio.wait_for(running, 2)
        assert nav.on_error() == nav.fail

    asyncio.run(scenario())


def test_an_unsupervised_host_leaves_a_handlers_bug_to_the_loop() -> None:
    async def scenario() -> None:
        nav, _core, _out, _ = host()
        assert nav.on_error() is None  # the intake hands it to the loop's exception handler
        seen: list[object] = []
        asyncio.get_running_loop().set_exception_handler(lambda loop, context: seen.append(context["exception"]))
        nav.fail(RuntimeError("a bug"))
        assert [str(e) for e in seen] == ["a bug"]

    asyncio.run(scenario())


def test_poses_poke_the_timer_at_most_every_pose_poke_s_other_inputs_at_once() -> None:
    from blackmetal.nav.host import POSE_POKE_S

    nav, core, _out, clock = host()
    pokes: list[float] = []
    nav.timer.poke = lambda: pokes.append(clock.now)  # type: ignore[method-assign]
    for _ in range(5):  # 50 Hz for 0.08 s
        nav.on_pose(b"p")
        clock.now += 0.02
    assert len(core.named("pose")) == 5 and pokes == pytest.approx([100.0, 100.06])  # at 0 and once POSE_POKE_S passed
    assert POSE_POKE_S == 0.05
    nav.on_health(b"h")
    nav.on_driver(b"d")
    assert len(pokes) == 4
