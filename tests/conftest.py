"""Shared fixtures, the tiers of the suite (set by folder), and how they share the workers.

The folder says what a test is (docs/contributing.md, "Tests"):

* ``unit/<package>/test_<module>.py``: the tests of one product module, on a fake clock where time matters;
* ``contract/``: one suite run against every implementation of an interface (memory and TCP);
* ``integration/``: real processes and Zenoh sessions on loopback; every test there is ``integration`` and ``slow``;
* ``project/``: the project's own rules (layers, lint, types, docs, this layout).

``python -m pytest -m "not slow"`` is the fast tier, run before each commit: everything outside
``integration/`` that is not marked ``slow`` (or ``integration``, which implies ``slow``) itself.
``python -m pytest`` (what CI runs) runs everything. A test outside ``integration/`` that starts
processes (uses the ``children`` fixture) must say so with ``@pytest.mark.integration``: collection
stops with its name otherwise. A fast-tier test that took longer than ``FAST_TEST_BUDGET_S`` is named
at the end of the run, so that the tier stays fast.

With pytest-xdist (``-n 3 --dist loadscope`` in pyproject.toml) each module runs on one worker, so
module fixtures start once, and the three workers run three modules at a time. Fast-tier tests still run
one at a time (a lock the workers share), so its CPU-bound tests (type checks, property tests) never
overlap its real-clock contract tests; a slow test may run beside them, as on any loaded machine.
"""

from __future__ import annotations

import asyncio
import fcntl
import os
from collections.abc import Callable, Coroutine, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from helpers import Child

if TYPE_CHECKING:
    import zenoh

#: A test that takes longer than this (s) belongs in the slow tier.
FAST_TEST_BUDGET_S = 5.0

#: Every gateway a test starts keeps its e-stop latch in that test's (or module's) own folder, never in the user's
#: ~/.local/state, and a gateway with no saved state there starts released, as `blackmetal up` starts its simulator:
#: the tests of the latch itself (tests/unit/gateway/test_latch.py) set both back to what a deployment has.
STATE_DIR_ENV = "BLACKMETAL_STATE_DIR"
os.environ["BLACKMETAL_UNSAFE_START_RELEASED"] = "true"


@pytest.fixture(autouse=True, scope="module")
def _state_dir_per_module(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Processes a module's fixtures start keep their e-stop latch in the module's own folder."""
    before = os.environ.get(STATE_DIR_ENV)
    os.environ[STATE_DIR_ENV] = str(tmp_path_factory.mktemp("state"))
    yield
    if before is None:
        os.environ.pop(STATE_DIR_ENV, None)
    else:
        os.environ[STATE_DIR_ENV] = before


@pytest.fixture(autouse=True)
def _state_dir_per_test(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """Processes a test starts keep their e-stop latch in the test's own folder."""
    monkeypatch.setenv(STATE_DIR_ENV, str(tmp_path_factory.mktemp("state")))


#: Every test under this folder is ``integration`` (and so ``slow``), marked or not.
INTEGRATION = Path(__file__).parent / "integration"


@pytest.hookimpl(tryfirst=True)  # before ``-m`` selects on the markers
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    unmarked: list[str] = []
    for item in items:
        if item.path.is_relative_to(INTEGRATION):
            if item.get_closest_marker("integration") is None:
                item.add_marker(pytest.mark.integration)
        elif "children" in getattr(item, "fixturenames", ()) and item.get_closest_marker("integration") is None:
            unmarked.append(item.nodeid)
        if item.get_closest_marker("integration") is not None and item.get_closest_marker("slow") is None:
            item.add_marker(pytest.mark.slow)
    if unmarked:
        raise pytest.UsageError(
            "these tests start processes (the children fixture) outside tests/integration/: mark them "
            "@pytest.mark.integration or move their module there: " + ", ".join(unmarked)
        )


@pytest.fixture(autouse=True)
def _fast_tier_one_at_a_time(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Under xdist, a fast-tier test holds a lock shared by the workers of this run (their common temp folder)."""
    if "PYTEST_XDIST_WORKER" not in os.environ or request.node.get_closest_marker("slow") is not None:
        yield
        return
    with open(tmp_path_factory.getbasetemp().parent / "fast-tier.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        yield


@pytest.fixture
def session() -> Iterator["zenoh.Session"]:
    """A Zenoh session on its own: no scouting, no listener, no peer (an edge tested in-process)."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    conf.insert_json5("listen/endpoints", "[]")
    with zenoh.open(conf) as opened:
        yield opened


_over_budget: list[tuple[str, float]] = []


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if report.when == "call" and "slow" not in report.keywords and report.duration > FAST_TEST_BUDGET_S:
        _over_budget.append((report.nodeid, report.duration))


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if _over_budget:
        terminalreporter.section("fast tier over budget")
        for nodeid, seconds in _over_budget:
            terminalreporter.line(f"{seconds:.1f} s  {nodeid}: not slow, but over {FAST_TEST_BUDGET_S:g} s; make it faster or mark it slow")


@pytest.fixture
def children() -> Iterator[list[Child]]:
    """Append every started Child here; all are stopped after the test, even on failure."""
    started: list[Child] = []
    yield started
    for child in reversed(started):
        child.stop()


@pytest.fixture(params=["asyncio", "uvloop"])
def run_loop(request: pytest.FixtureRequest) -> Callable[[Coroutine[Any, Any, None]], None]:
    """Runs a coroutine to its end on the standard event loop, then (a second test) on uvloop, which the services use."""
    if request.param == "uvloop":
        uvloop = pytest.importorskip("uvloop", reason="uvloop is not installed")
        factory: Callable[[], asyncio.AbstractEventLoop] = uvloop.new_event_loop
    else:
        factory = asyncio.new_event_loop

    def run(main: Coroutine[Any, Any, None]) -> None:
        with asyncio.Runner(loop_factory=factory) as runner:
            runner.run(main)

    return run
