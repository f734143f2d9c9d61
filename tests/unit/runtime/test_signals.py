"""SIGINT and SIGTERM as a stop request (blackmetal.runtime.signals), sent to this very process."""

from __future__ import annotations

import asyncio
import os
import signal
from collections.abc import Iterator

import pytest

from blackmetal.runtime.signals import STOP_SIGNALS, loop_stop_on_signals, stop_on_signals


@pytest.fixture
def handlers_restored() -> Iterator[None]:
    saved = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
    yield
    for sig, handler in saved.items():
        signal.signal(sig, handler)


@pytest.mark.parametrize("sig", STOP_SIGNALS)
def test_a_stop_signal_sets_the_event_of_a_thread_based_tool(sig: signal.Signals, handlers_restored: None) -> None:
    stop = stop_on_signals()
    assert not stop.is_set()
    os.kill(os.getpid(), sig)
    for _ in range(50):  # the documented way to wait: with a timeout, so the main thread runs the handler
        if stop.wait(0.1):
            break
    assert stop.is_set()


@pytest.mark.parametrize("sig", STOP_SIGNALS)
def test_a_stop_signal_sets_the_event_of_an_asyncio_service(sig: signal.Signals, handlers_restored: None) -> None:
    async def scenario() -> bool:
        stop = loop_stop_on_signals()
        os.kill(os.getpid(), sig)
        await asyncio.wait_for(stop.wait(), 5.0)
        return stop.is_set()

    assert asyncio.run(scenario())
