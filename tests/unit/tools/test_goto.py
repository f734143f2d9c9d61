"""goto: the goal the arguments ask for, the progress line and the result sentence, the exit codes, Ctrl-C's cancel,
and one sentence when no navigation service answers. Zenoh is a stand-in session here."""

from __future__ import annotations

import argparse
import io
import json
import math
from types import SimpleNamespace
from typing import Any

import pytest

from blackmetal.runtime.zenoh_setup import ZenohSettings
from blackmetal.schemas import (
    GatewayParams,
    GoalState,
    Keys,
    NavCancelReply,
    NavFeedback,
    NavGoal,
    NavGoalReply,
    NavMove,
    NavResult,
    PlanarPose,
    encode,
)
from blackmetal.tools import goto
from blackmetal.tools.client import ToolError

from .fake_session import FakeSession, reply

KEYS = Keys()


def args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    goto.build_parser(parser)
    return parser.parse_args(list(argv))


def feedback(goal_id: str, state: GoalState, left: float = 0.5, eta: float = 1.0, elapsed: float = 1.0, reason: str = "") -> NavFeedback:
    return NavFeedback(
        stamp=0.0,
        goal_id=goal_id,
        state=state,
        pose=PlanarPose(x=0.1, y=0.2, yaw=0.0),
        goal=PlanarPose(x=0.5, y=0.3, yaw=math.pi / 2),
        distance_remaining=left,
        eta=eta,
        elapsed=elapsed,
        reason=reason,
    )


def sample(message: Any) -> SimpleNamespace:
    return SimpleNamespace(payload=encode(message))


def test_the_arguments_make_a_goal_or_a_move() -> None:
    key, goal = goto.request_of(args("0.5", "-0.3", "90"), "a" * 32)
    assert key == "nav_goal" and isinstance(goal, NavGoal)
    assert (goal.x, goal.y, goal.frame, goal.goal_id) == (0.5, -0.3, "map", "a" * 32) and goal.yaw == pytest.approx(math.pi / 2)
    key, goal = goto.request_of(args("1", "2", "--frame", "odom"), "b" * 32)
    assert isinstance(goal, NavGoal) and goal.yaw is None and goal.frame == "odom"
    key, move = goto.request_of(args("--move", "0.5"), "c" * 32)
    assert key == "nav_move" and isinstance(move, NavMove) and (move.distance, move.angle) == (0.5, 0.0)
    key, move = goto.request_of(args("--turn", "-90"), "c" * 32)
    assert isinstance(move, NavMove) and move.angle == pytest.approx(-math.pi / 2)


@pytest.mark.parametrize(
    ("argv", "sentence"),
    [
        ([], "where to\\? give X Y \\[YAW\\]"),
        (["1"], "where to"),
        (["1", "2", "--move", "1"], "one of the three"),
        (["--move", "1", "--turn", "90"], "one of the three"),
        (["nan", "1"], "X must be a finite number"),
        (["--turn", "inf"], "--turn must be a finite number"),
    ],
)
def test_arguments_that_mean_nothing_are_one_sentence(argv: list[str], sentence: str) -> None:
    with pytest.raises(ToolError, match=sentence):
        goto.request_of(args(*argv), "a" * 32)


def test_the_progress_line_and_the_result_sentences() -> None:
    line = goto.progress_line(feedback("a" * 32, GoalState.EXECUTING, left=0.42, eta=3.0, elapsed=1.0))
    assert line == "[######..................]  0.420 m left, eta  3.0 s, executing (1.0 s)"
    assert goto.progress_line(feedback("a" * 32, GoalState.SUCCEEDED, left=0.0, eta=0.0)).startswith("[" + "#" * goto.BAR + "]")
    done = feedback("a" * 32, GoalState.SUCCEEDED, elapsed=4.25)
    assert goto.result_sentence(done.state, "", done.goal, done.pose, done.elapsed) == (
        "reached (0.500, 0.300, 90.0°) in map in 4.2 s; the robot is at (0.100, 0.200, 0.0°) in map"
    )
    assert goto.result_sentence(GoalState.ABORTED, "e-stop engaged", None, None, 2.0) == "goal aborted after 2.0 s: e-stop engaged"


class Nav:
    """A navigation service behind a FakeSession: answers a goal, then plays ``states`` on the feedback subscriber."""

    def __init__(self, states: list[GoalState], accepted: bool = True, reason: str = "", result: NavResult | None = None) -> None:
        self.states, self.accepted, self.reason, self.result = states, accepted, reason, result
        self.goals: list[dict[str, Any]] = []
        self.cancels: list[dict[str, Any]] = []
        self.session = FakeSession(
            {
                KEYS.nav_params: [reply(GatewayParams(stamp=0.0, params=[]))],
                KEYS.nav_goal: self.on_goal,
                KEYS.nav_move: self.on_goal,
                KEYS.nav_cancel: self.on_cancel,
                KEYS.nav_result: lambda payload: [reply(self.result)] if self.result is not None else [],
            }
        )

    def on_goal(self, payload: bytes) -> list[Any]:
        goal = json.loads(payload)
        self.goals.append(goal)
        if self.accepted:
            for state in self.states:
                self.session.subscribers[KEYS.nav_feedback](sample(feedback(goal["goal_id"], state)))
            self.session.subscribers[KEYS.nav_feedback](sample(feedback("f" * 32, GoalState.ABORTED)))  # another goal's
        return [reply(NavGoalReply(accepted=self.accepted, goal_id=goal["goal_id"] if self.accepted else None, reason=self.reason))]

    def on_cancel(self, payload: bytes) -> list[Any]:
        self.cancels.append(json.loads(payload))
        return [reply(NavCancelReply(canceled=[self.cancels[-1]["goal_id"]]))]


def run(monkeypatch: pytest.MonkeyPatch, nav: Nav | None, *argv: str) -> int:
    """``goto.run`` against ``nav`` (None: nothing answers on any key)."""
    session = FakeSession() if nav is None else nav.session
    monkeypatch.setattr(goto, "connect", lambda a: (KEYS, ZenohSettings(connect=["tcp/127.0.0.1:7447"]), session))
    return goto.run(args(*argv, "--wait", "0.2"))


def test_a_goal_that_succeeds_ends_with_its_sentence_and_0(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    nav = Nav([GoalState.ACCEPTED, GoalState.EXECUTING, GoalState.SUCCEEDED])
    assert run(monkeypatch, nav, "0.5", "0.3", "90") == 0
    assert nav.goals[0]["x"] == 0.5 and nav.goals[0]["yaw"] == pytest.approx(math.pi / 2)
    out = capsys.readouterr().out
    assert f"blackmetal goto: goal {nav.goals[0]['goal_id']} accepted on robot; Ctrl-C cancels it" in out
    assert out.endswith("blackmetal goto: reached (0.500, 0.300, 90.0°) in map in 1.0 s; the robot is at (0.100, 0.200, 0.0°) in map\n")


def test_an_aborted_move_and_a_rejected_goal_end_with_1(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    nav = Nav([GoalState.EXECUTING, GoalState.ABORTED])
    assert run(monkeypatch, nav, "--move", "0.5") == 1
    assert nav.goals[0]["distance"] == 0.5
    assert "blackmetal goto: goal aborted after 1.0 s" in capsys.readouterr().out
    rejected = Nav([], accepted=False, reason="the robot is e-stopped: release it first (blackmetal estop off)")
    assert run(monkeypatch, rejected, "1", "1") == 1
    assert capsys.readouterr().out == "blackmetal goto: goal rejected: the robot is e-stopped: release it first (blackmetal estop off)\n"


def test_the_result_tells_the_end_when_the_last_feedback_was_lost(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(goto, "ASK_RESULT_AFTER_S", 0.05)
    done = NavResult(found=True, goal_id="a" * 32, state=GoalState.CANCELED, reason="a newer goal preempted it", elapsed=2.0)
    nav = Nav([GoalState.EXECUTING], result=done)
    assert run(monkeypatch, nav, "1", "0") == 1
    assert "blackmetal goto: goal canceled after 2.0 s: a newer goal preempted it" in capsys.readouterr().out


def test_a_silent_service_is_one_sentence(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(goto, "ASK_RESULT_AFTER_S", 0.05)
    monkeypatch.setattr(goto, "SILENCE_S", 0.3)
    assert run(monkeypatch, Nav([GoalState.EXECUTING]), "1", "0") == 1
    assert "blackmetal goto: the navigation service on robot went silent (0.3 s without feedback" in capsys.readouterr().err


def test_no_navigation_service_is_one_sentence(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(goto.time, "sleep", lambda _s: None)
    assert run(monkeypatch, None, "1", "2") == 1
    assert capsys.readouterr().err == (
        "blackmetal goto: no navigation service on robot/nav/goal: is `blackmetal nav` running (blackmetal up starts it)?\n"
    )


def test_ctrl_c_cancels_the_goal_and_exits_130(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    nav = Nav([GoalState.EXECUTING])

    def interrupted(*_: Any, **__: Any) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(goto, "follow", interrupted)
    assert run(monkeypatch, nav, "1", "0") == goto.INTERRUPTED
    assert nav.cancels == [{"goal_id": nav.goals[0]["goal_id"]}]
    assert capsys.readouterr().out.endswith("blackmetal goto: interrupted: goal canceled, the robot stops\n")


def test_ctrl_c_before_the_goal_went_out_exits_130_quietly(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    def interrupted(*_: Any) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(goto, "require_nav", interrupted)
    assert run(monkeypatch, Nav([]), "1", "0") == goto.INTERRUPTED
    assert capsys.readouterr().err == "\nblackmetal goto: interrupted before the goal was sent\n"


def test_follow_on_a_terminal_redraws_one_line() -> None:
    follower = goto.Follower("a" * 32)
    for state in (GoalState.EXECUTING, GoalState.EXECUTING, GoalState.SUCCEEDED):
        follower.on_sample(sample(feedback("a" * 32, state)))
    follower.on_sample(SimpleNamespace(payload=b"not json"))  # skipped
    out = io.StringIO()
    assert goto.follow(FakeSession(), KEYS, follower, out, tty=True) == 0
    text = out.getvalue()
    assert text.count("\r\x1b[2K") == 3 and text.count("\n") == 2 and text.endswith("in map\n")


def test_cancel_says_what_came_of_it() -> None:
    nothing = FakeSession({KEYS.nav_cancel: [reply(NavCancelReply(canceled=[], reason="no goal runs"))]})
    assert goto.cancel(nothing, KEYS, "a" * 32) == "nothing to cancel (no goal runs)"
    assert "command timeout stops the robot" in goto.cancel(FakeSession(), KEYS, "a" * 32)


def test_ctrl_c_while_the_goal_is_sent_cancels_it_by_its_id(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    nav = Nav([])

    def interrupted(session: Any, keys: Keys, key: str, request: Any, timeout: float) -> NavGoalReply:
        nav.on_goal(encode(request))  # it reached the service, the answer did not reach us
        raise KeyboardInterrupt

    monkeypatch.setattr(goto, "send", interrupted)
    assert run(monkeypatch, nav, "1", "0") == goto.INTERRUPTED
    assert nav.cancels == [{"goal_id": nav.goals[0]["goal_id"]}]
    assert "blackmetal goto: interrupted: goal canceled, the robot stops" in capsys.readouterr().out
