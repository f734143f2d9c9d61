"""The recorder: Zenoh's callbacks only queue; its own thread writes, flushes and finishes the file."""

from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from blackmetal.recording.reader import read_mcap
from blackmetal.recording.recorder import SessionRecorder
from blackmetal.recording.writer import McapRecording
from blackmetal.schemas import Keys, encode, make_pose


class Session:
    def __init__(self) -> None:
        self.callbacks: dict[str, Any] = {}

    def declare_subscriber(self, key: str, callback: Any) -> SimpleNamespace:
        self.callbacks[key] = callback
        return SimpleNamespace(undeclare=lambda: None)


def test_samples_and_notes_land_in_the_file(tmp_path: Path) -> None:
    session = Session()
    recording = McapRecording(tmp_path / "r.mcap", Keys())
    recorder = SessionRecorder(session, ["robot/**"], recording, flush_period=0.05)  # type: ignore[arg-type]
    pose = encode(make_pose(1_795_000_000.0, 1.0, 2.0, 0.0))
    for _ in range(3):
        session.callbacks["robot/**"](SimpleNamespace(key_expr="robot/pose", payload=SimpleNamespace(to_bytes=lambda: pose)))
    recorder.note("blackmetal.square", {"direction": "clockwise"})
    time.sleep(0.1)
    recorder.stop()
    assert recorder.error is None
    read = read_mcap(str(tmp_path / "r.mcap"), ["robot/pose"])
    assert read.channels["robot/pose"].payloads == [pose] * 3
    assert read.metadata[-1] == ("blackmetal.square", {"direction": "clockwise"})
