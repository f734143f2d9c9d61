"""One position move's plan and course (:mod:`blackmetal.gateway.position`), fed readings by hand."""

from __future__ import annotations

import pytest

from blackmetal.gateway.position import (
    DEADLINE_FACTOR,
    DEADLINE_MARGIN_S,
    MAX_RESENDS,
    MAX_TRAVEL_M,
    STALL_S,
    TOLERANCE_IMPULSES,
    MovePlan,
    Run,
    Step,
    plan_move,
    travel_refusal,
)

IPM = 1000.0  # impulses per metre, both wheels, for round figures


def test_a_plan_is_whole_impulses_its_time_at_the_robots_speed_and_segments_within_the_keepalive() -> None:
    plan = plan_move(1.0, -0.5, IPM, 2 * IPM, speed=0.25, segment_s=5.0)
    assert (plan.left, plan.right) == (1000, -1000)
    assert plan.expected == pytest.approx(4.0) and plan.segments == 1
    assert plan.deadline_after == pytest.approx(4.0 * DEADLINE_FACTOR + DEADLINE_MARGIN_S)
    assert plan_move(5.0, 5.0, IPM, IPM, 0.25, 5.0).segments == 4  # 20 s in four 5 s segments
    assert plan_move(1.25, 1.25, IPM, IPM, 0.25, 5.0).segments == 1  # exactly one segment's time is one segment
    assert plan_move(0.0, 0.0, IPM, IPM, 0.25, 5.0) == MovePlan(0, 0, 1, 0.0, DEADLINE_MARGIN_S)


def test_travel_beyond_the_limit_is_refused() -> None:
    assert travel_refusal(MAX_TRAVEL_M, -MAX_TRAVEL_M) is None
    assert (
        travel_refusal(0.0, -MAX_TRAVEL_M - 1)
        == f"a wheel travel of {MAX_TRAVEL_M + 1:g} m is beyond the {MAX_TRAVEL_M:g} m a position move may take: send shorter moves"
    )


def run_of(left: int, right: int, segments: int = 1) -> Run:
    return Run("m1", "nav", MovePlan(left, right, segments, 1.0, 2.5), accepted_at=10.0)


def test_the_first_reading_is_the_start_and_the_command_goes_out_from_it() -> None:
    run = run_of(500, 400)
    assert run.remaining() == (500, 400) and run.deadline == 12.5
    run.poll_sent()
    assert run.on_reading(100, -200, 10.01) is Step.SEND
    assert run.start == (100, -200) and run.command == (500, 400)
    assert run.target() == (600, -600)  # as the robot reports: the right wheel mirrored
    run.command_sent(10.01)
    run.poll_sent()
    assert run.on_reading(300, -360, 10.5) is Step.NOTHING and run.remaining() == (300, 240)


def drive_to(run: Run, reading: tuple[int, int], now: float) -> Step:
    run.poll_sent()
    return run.on_reading(*reading, now)


def test_done_when_the_wheels_stand_at_the_target() -> None:
    run = run_of(500, 500)
    assert drive_to(run, (0, 0), 0.0) is Step.SEND
    run.command_sent(0.0)
    assert drive_to(run, (499, -498), 1.0) is Step.NOTHING  # there, but was it still moving? one more reading tells
    assert drive_to(run, (499, -498), 1.04) is Step.DONE
    assert TOLERANCE_IMPULSES >= 2


def test_a_reading_asked_before_the_command_tells_nothing() -> None:
    run = run_of(500, 500)
    run.poll_sent()
    run.poll_sent()  # a second reading was asked before the first came back
    assert run.on_reading(0, 0, 0.0) is Step.SEND
    run.command_sent(0.0)
    assert run.on_reading(0, 0, 0.01) is Step.NOTHING  # the one asked before the command: the wheels had not started
    assert run.segment == 1 and not run.want_send


def test_segments_run_one_after_the_other_each_from_where_the_wheels_stand() -> None:
    run = run_of(900, 900, segments=3)
    assert drive_to(run, (0, 0), 0.0) is Step.SEND and run.command == (300, 300)
    run.command_sent(0.0)
    drive_to(run, (302, -302), 1.0)  # overshot by two
    assert drive_to(run, (302, -302), 1.04) is Step.SEND and run.command == (298, 298)  # made good by the next
    run.command_sent(1.04)
    drive_to(run, (600, -600), 2.0)
    assert drive_to(run, (600, -600), 2.04) is Step.SEND and run.command == (300, 300) and run.segment == 3
    run.command_sent(2.04)
    drive_to(run, (900, -900), 3.0)
    assert drive_to(run, (900, -900), 3.04) is Step.DONE


def test_nothing_to_move_is_done_at_the_first_reading() -> None:
    assert drive_to(run_of(0, 0), (5, -5), 0.0) is Step.DONE


def test_a_dropped_command_goes_out_again_from_the_next_reading_at_most_max_resends_times() -> None:
    run = run_of(500, 500)
    drive_to(run, (0, 0), 0.0)
    run.command_sent(0.0)
    for _ in range(MAX_RESENDS):
        assert run.dropped()
        assert drive_to(run, (0, 0), 0.1) is Step.SEND and run.command == (500, 500)
        run.command_sent(0.1)
    assert not run.dropped()


def test_wheels_that_stop_short_stall_after_stall_s() -> None:
    run = run_of(500, 500)
    drive_to(run, (0, 0), 0.0)
    run.command_sent(5.0)
    assert drive_to(run, (0, 0), 5.0 + STALL_S - 0.01) is Step.NOTHING  # counted from the command, not the reading
    assert drive_to(run, (0, 0), 5.0 + STALL_S) is Step.STALLED
    run.poll_lost()
    assert run.readings == 4


def test_a_deferred_command_goes_out_from_the_next_reading_and_counts_no_resend() -> None:
    run = run_of(500, 500)
    assert drive_to(run, (0, 0), 0.0) is Step.SEND
    run.defer()
    assert drive_to(run, (0, 0), 0.02) is Step.SEND and run.resends == 0 and run.command == (500, 500)
