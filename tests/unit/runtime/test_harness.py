"""Child processes (blackmetal.runtime.harness): the ready announcement on its pipe, the failures that carry the child's last lines."""

from __future__ import annotations

import json
import os
import signal
import time

import pytest

from blackmetal.runtime.harness import READY_FD_ENV, ChildFailed, ServiceProcess, announce_ready, stop_in_order

ANNOUNCE = "from blackmetal.runtime.harness import announce_ready; print('starting'); announce_ready('svc', ports=[6650, 6640])"


def test_a_service_announces_readiness_once_as_one_json_line(monkeypatch: pytest.MonkeyPatch) -> None:
    read_fd, write_fd = os.pipe()
    monkeypatch.setenv(READY_FD_ENV, str(write_fd))
    announce_ready("gateway", prefix="robot")
    assert READY_FD_ENV not in os.environ  # a second announcement, or a grandchild, finds no pipe
    with os.fdopen(read_fd) as pipe:
        assert [json.loads(line) for line in pipe] == [{"service": "gateway", "prefix": "robot"}]
    announce_ready("gateway")  # no harness: nothing, no error


def test_a_pipe_the_parent_closed_or_nonsense_is_no_error(monkeypatch: pytest.MonkeyPatch) -> None:
    read_fd, write_fd = os.pipe()
    os.close(read_fd)
    monkeypatch.setenv(READY_FD_ENV, str(write_fd))
    announce_ready("gateway")
    monkeypatch.setenv(READY_FD_ENV, "not-a-number")
    announce_ready("gateway")


def test_the_parent_reads_the_announcement_and_keeps_the_childs_lines() -> None:
    child = ServiceProcess("svc", ["-c", ANNOUNCE])
    try:
        assert child.wait_ready(20) == {"service": "svc", "ports": [6650, 6640]}
        assert child.wait_ready(0) is child.ready_info  # read once
        assert child.wait(20) == 0 and child.output() == "starting" and child.tail() == "    starting"
    finally:
        child.stop()


def test_a_child_that_exits_before_it_is_ready_fails_with_its_last_lines() -> None:
    child = ServiceProcess("svc", ["-c", "import sys; print('bad setting'); sys.exit(2)"])
    with pytest.raises(ChildFailed) as error:
        child.wait_ready(20)
    assert str(error.value) == "svc exited with code 2 before it was ready; its last lines:\n    bad setting"
    assert error.value.child is child
    child.stop()


def test_a_silent_child_fails_after_its_timeout_and_is_stopped_by_a_signal() -> None:
    child = ServiceProcess("svc", ["-c", "import time; time.sleep(30)"])
    with pytest.raises(ChildFailed, match=r"^svc did not become ready within 0.2 s; its last lines:\n    \(no output\)$"):
        child.wait_ready(0.2)
    assert child.stop(signal.SIGTERM, timeout=10) == -signal.SIGTERM


def test_an_interactive_child_answers_line_by_line() -> None:
    echo = "import sys\nfor line in sys.stdin:\n    print(line.strip().upper(), flush=True)"
    child = ServiceProcess("echo", ["-c", echo], interactive=True)
    try:
        assert child.request("ping", timeout=20) == "PING"
        assert child.request("pong", timeout=20) == "PONG"
    finally:
        child.stop()
    once = ServiceProcess("once", ["-c", "pass"])
    with pytest.raises(AssertionError, match="not an interactive child"):
        once.request("ping")
    once.stop()


def test_groups_stop_in_order_and_what_outlives_the_budget_is_killed() -> None:
    stubborn = "import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); print('up', flush=True); time.sleep(30)"
    first = ServiceProcess("first", ["-c", "import time; print('up', flush=True); time.sleep(30)"])
    second = ServiceProcess("second", ["-c", stubborn])
    deadline = time.monotonic() + 20
    while not (first.output() == second.output() == "up") and time.monotonic() < deadline:
        time.sleep(0.01)  # the second child ignores SIGINT from here on
    stop_in_order([[first], [second]], budget=1.0)
    assert first.poll() is not None and first.poll() != -signal.SIGKILL
    assert second.poll() == -signal.SIGKILL
