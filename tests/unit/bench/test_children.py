"""The bench's signals: the first SIGTERM raises KeyboardInterrupt so every finally runs, and is remembered."""

from __future__ import annotations

import os
import signal

import pytest

from blackmetal.bench import children


def test_sigterm_is_ctrl_c_once_and_the_handlers_come_back() -> None:
    before = signal.getsignal(signal.SIGTERM)
    with children.stopping_on_signals():
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGTERM)
        assert children.stop_signal() == signal.SIGTERM
        os.kill(os.getpid(), signal.SIGINT)  # already stopping: only noted
    assert signal.getsignal(signal.SIGTERM) is before


def test_stop_all_with_nothing_started_is_a_no_op() -> None:
    children.stop_all(grace=0.1)
    assert children._children == []
