"""Shared fixtures: every process a test starts is stopped when it ends."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from helpers import Child


@pytest.fixture
def children() -> Iterator[list[Child]]:
    """Append every started Child here; all are stopped after the test, even on failure."""
    started: list[Child] = []
    yield started
    for child in reversed(started):
        child.stop()
