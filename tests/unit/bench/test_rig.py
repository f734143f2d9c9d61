"""The rig's readings of a process: resident memory and CPU share, from /proc (of this process)."""

from __future__ import annotations

import os
import time
from contextlib import ExitStack
from pathlib import Path

from blackmetal.bench.rig import cpu_seconds, cpu_window, latch_args, rss_mb


def test_memory_and_cpu_of_a_process() -> None:
    me = os.getpid()
    assert 5 < rss_mb(me) < 10_000
    before = cpu_seconds(me)
    end = time.process_time() + 0.05
    while time.process_time() < end:
        pass
    assert cpu_seconds(me) > before
    (share,) = cpu_window({"me": me}, 0.05).values()
    assert 0.0 <= share < 2.0


def test_a_gateways_latch_lives_in_a_folder_of_its_own_removed_at_the_end() -> None:
    with ExitStack() as stack:
        flag, folder, released = latch_args(stack)
        assert flag == "--state-dir" and Path(folder).is_dir() and released == "--unsafe-start-released"
    assert not Path(folder).exists()
