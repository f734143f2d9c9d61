"""``blackmetal goto X Y [YAW]``: send the robot to (X, Y), facing YAW degrees, and follow it there.

The goal goes to ``<prefix>/nav/goal`` (the navigation service, which ``blackmetal up`` starts); a progress line
follows its ``nav/feedback`` (distance left, time left, state) and the command ends with the result: exit 0 when the
goal succeeded, 1 when it was rejected, canceled or aborted (the sentence says why). Ctrl-C cancels the goal
(``nav/cancel``) and exits 130. ``--frame odom`` gives X, Y in the robot's odometry frame instead of the map;
``--move M`` drives M metres straight and ``--turn DEG`` turns on the spot (``nav/move``).
"""

from __future__ import annotations

import argparse
import math
import queue
import sys
import time
import uuid
from dataclasses import dataclass, field
from typing import Any, TextIO

from blackmetal.schemas import (
    GatewayParams,
    GoalState,
    Keys,
    NavCancel,
    NavCancelReply,
    NavFeedback,
    NavGoal,
    NavGoalReply,
    NavMove,
    NavResult,
    NavResultQuery,
    encode,
    to_bytes,
)

from .client import ToolError, add_client_arguments, connect, decoded, first_reply, query, tool

#: Width of the progress bar, in characters.
BAR = 24
#: Without feedback for this long the tool asks nav/result (feedback is telemetry: one can be lost).
ASK_RESULT_AFTER_S = 1.0
#: Without feedback or an answer for this long, the navigation service is taken for gone.
SILENCE_S = 5.0
#: Off a terminal a progress line is printed at most this often (s).
PIPE_LINE_EVERY_S = 1.0
#: The exit code of a run Ctrl-C ended (128 + SIGINT), as a shell reports it.
INTERRUPTED = 130


def no_service(keys: Keys) -> str:
    return f"no navigation service on {keys.nav_goal}: is `blackmetal nav` running (blackmetal up starts it)?"


def request_of(args: argparse.Namespace, goal_id: str) -> tuple[str, NavGoal | NavMove]:
    """The key (``nav_goal`` or ``nav_move``) and payload the arguments ask for; ToolError for a mix that means nothing."""
    moves = [name for name in ("move", "turn") if getattr(args, name) is not None]
    if moves:
        if args.x is not None or len(moves) > 1:
            raise ToolError("give X Y [YAW], or --move METRES, or --turn DEGREES: one of the three")
        if args.move is not None:
            return "nav_move", NavMove(distance=_finite("--move", args.move), goal_id=goal_id)
        return "nav_move", NavMove(angle=math.radians(_finite("--turn", args.turn)), goal_id=goal_id)
    if args.x is None or args.y is None:
        raise ToolError("where to? give X Y [YAW] (metres, degrees), or --move METRES, or --turn DEGREES")
    yaw = None if args.yaw is None else math.radians(_finite("YAW", args.yaw))
    return "nav_goal", NavGoal(x=_finite("X", args.x), y=_finite("Y", args.y), yaw=yaw, frame=args.frame, goal_id=goal_id)


def _finite(name: str, value: float) -> float:
    if not math.isfinite(value):
        raise ToolError(f"{name} must be a finite number, got {value}")
    return float(value)


def bar(fraction: float, width: int = BAR) -> str:
    filled = round(min(max(fraction, 0.0), 1.0) * width)
    return "[" + "#" * filled + "." * (width - filled) + "]"


def progress_line(feedback: NavFeedback) -> str:
    """One line: the bar (time elapsed over time elapsed and left), distance left, eta, state."""
    total = feedback.elapsed + feedback.eta
    fraction = 1.0 if feedback.state is GoalState.SUCCEEDED else (feedback.elapsed / total if total > 0 else 0.0)
    return (
        f"{bar(fraction)} {feedback.distance_remaining:6.3f} m left, eta {feedback.eta:4.1f} s, {feedback.state.value}"
        f" ({feedback.elapsed:.1f} s)"
    )


def _pose_text(x: float, y: float, yaw: float, frame: str) -> str:
    return f"({x:.3f}, {y:.3f}, {math.degrees(yaw):.1f}°) in {frame}"


def result_sentence(state: GoalState | None, reason: str, goal: Any, pose: Any, elapsed: float) -> str:
    """What became of the goal, one sentence; ``goal`` and ``pose``: PlanarPose or None."""
    at = f"; the robot is at {_pose_text(pose.x, pose.y, pose.yaw, pose.frame)}" if pose is not None else ""
    if state is GoalState.SUCCEEDED:
        where = _pose_text(goal.x, goal.y, goal.yaw, goal.frame) if goal is not None else "the goal"
        return f"reached {where} in {elapsed:.1f} s{at}"
    said = f": {reason}" if reason else ""
    return f"goal {state.value if state is not None else 'lost'} after {elapsed:.1f} s{said}{at}"


@dataclass
class Follower:
    """Feedback of one goal, handed from Zenoh's thread to the tool's; the callback only queues."""

    goal_id: str
    items: queue.SimpleQueue[NavFeedback] = field(default_factory=queue.SimpleQueue)

    def on_sample(self, sample: Any) -> None:
        feedback = decoded(NavFeedback, sample)
        if feedback is not None and feedback.goal_id == self.goal_id:
            self.items.put(feedback)


def follow(session: Any, keys: Keys, follower: Follower, out: TextIO, tty: bool, clock: Any = time.monotonic) -> int:
    """Print progress until the goal ends; its sentence, and 0 for succeeded, 1 otherwise."""
    last_news, last_line = clock(), -math.inf  # off a terminal, the first progress line at once, then one a second
    next_ask = last_news + ASK_RESULT_AFTER_S
    while True:
        try:
            feedback: NavFeedback | None = follower.items.get(timeout=0.1)
        except queue.Empty:
            feedback = None
        now = clock()
        if feedback is not None:
            last_news, next_ask = now, now + ASK_RESULT_AFTER_S
            if feedback.state.done:
                if tty:
                    out.write("\r\x1b[2K" + progress_line(feedback) + "\n")
                sentence = result_sentence(feedback.state, feedback.reason, feedback.goal, feedback.pose, feedback.elapsed)
                return _end(out, feedback.state, sentence)
            if tty or now - last_line >= PIPE_LINE_EVERY_S:
                out.write("\r\x1b[2K" + progress_line(feedback) if tty else progress_line(feedback) + "\n")
                out.flush()
                last_line = now
            continue
        if now >= next_ask:  # feedback is telemetry, one may be lost: the result says whether the goal ended
            next_ask = now + ASK_RESULT_AFTER_S
            payload = encode(NavResultQuery(goal_id=follower.goal_id))
            result = first_reply(session.get(keys.nav_result, payload=payload, timeout=2.0), NavResult)
            if result is not None:
                last_news = clock()
                if not result.found:
                    raise ToolError(f"the navigation service on {keys.prefix} no longer knows goal {follower.goal_id} (was it restarted?)")
                if result.state is not None and result.state.done:
                    sentence = result_sentence(result.state, result.reason, result.goal, result.pose, result.elapsed)
                    return _end(out, result.state, sentence, newline=tty)
        if now - last_news >= SILENCE_S:
            raise ToolError(
                f"the navigation service on {keys.prefix} went silent ({SILENCE_S:g} s without feedback or an answer on "
                f"{keys.nav_result}): is `blackmetal nav` still running?"
            )


def _end(out: TextIO, state: GoalState, sentence: str, newline: bool = False) -> int:
    if newline:
        out.write("\n")
    out.write(f"blackmetal goto: {sentence}\n")
    out.flush()
    return 0 if state is GoalState.SUCCEEDED else 1


def cancel(session: Any, keys: Keys, goal_id: str, timeout: float = 2.0) -> str:
    """Cancel ``goal_id``; what came of it, one sentence."""
    replies = session.get(keys.nav_cancel, payload=encode(NavCancel(goal_id=goal_id)), timeout=timeout)
    answer = first_reply(replies, NavCancelReply)
    if answer is None:
        return f"no answer on {keys.nav_cancel}: the gateway's command timeout stops the robot if nav is gone"
    if goal_id in answer.canceled:
        return "goal canceled, the robot stops"
    return f"nothing to cancel ({answer.reason})" if answer.reason else "nothing to cancel: the goal had ended"


def require_nav(session: Any, keys: Keys, wait: float) -> None:
    """The navigation service answers on this prefix within ``wait`` s (its parameters, a harmless get), or ToolError."""
    deadline = time.monotonic() + wait
    while query(session, keys.nav_params, GatewayParams, timeout=min(1.0, max(wait, 0.1))) is None:
        if time.monotonic() > deadline:
            raise ToolError(no_service(keys))
        time.sleep(0.2)


def send(session: Any, keys: Keys, key: str, request: NavGoal | NavMove, timeout: float) -> NavGoalReply:
    """The goal or move sent once; the service's answer, or ToolError."""
    for reply in session.get(getattr(keys, key), payload=encode(request), timeout=timeout):
        if reply.err is not None:
            raise ToolError(f"the navigation service refused the request: {to_bytes(reply.err.payload).decode(errors='replace')}")
        if reply.ok is not None and (answer := decoded(NavGoalReply, reply.ok)) is not None:
            return answer
    raise ToolError(no_service(keys))


@tool("goto")
def go(args: argparse.Namespace) -> int:
    """Send the goal and follow it (Ctrl-C while it runs cancels it)."""
    goal_id = uuid.uuid4().hex
    key, request = request_of(args, goal_id)
    keys, _settings, session = connect(args)
    with session:
        require_nav(session, keys, args.wait)
        follower = Follower(goal_id)
        subscriber = session.declare_subscriber(keys.nav_feedback, follower.on_sample)  # before the goal: its first feedback counts
        try:
            answer = send(session, keys, key, request, timeout=max(args.wait, 2.0))
            if not answer.accepted:
                print(f"blackmetal goto: goal rejected: {answer.reason}", flush=True)
                return 1
            what = "move" if key == "nav_move" else "goal"
            print(f"blackmetal goto: {what} {answer.goal_id} accepted on {keys.prefix}; Ctrl-C cancels it", flush=True)
            return follow(session, keys, follower, sys.stdout, sys.stdout.isatty())
        except KeyboardInterrupt:  # the goal went out (its id is ours): whatever its answer, it is canceled
            print(f"\nblackmetal goto: interrupted: {cancel(session, keys, goal_id)}", flush=True)
            return INTERRUPTED
        finally:
            subscriber.undeclare()


def run(args: argparse.Namespace) -> int:
    """:func:`go`; a Ctrl-C before the goal went out ends quietly too (130), not in a traceback."""
    try:
        return go(args)
    except KeyboardInterrupt:
        print("\nblackmetal goto: interrupted before the goal was sent", file=sys.stderr, flush=True)
        return INTERRUPTED


def build_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("x", type=float, nargs="?", metavar="X", help="where to, metres (in --frame)")
    parser.add_argument("y", type=float, nargs="?", metavar="Y", help="where to, metres")
    parser.add_argument("yaw", type=float, nargs="?", metavar="YAW", help="heading on arrival, degrees (default: any)")
    parser.add_argument("--frame", default="map", help="the frame of X Y YAW: map (default) or odom")
    parser.add_argument("--move", type=float, metavar="METRES", help="instead: drive this far straight ahead (negative: back)")
    parser.add_argument("--turn", type=float, metavar="DEGREES", help="instead: turn on the spot this much (positive: left)")
    add_client_arguments(parser)
